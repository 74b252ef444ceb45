"""The Zenoh binding: key expressions, settings, sessions, the Thing server, the client, discovery."""
