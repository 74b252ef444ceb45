"""The mesh's command-line commands: router, adapter, recorder and a mesh client's (things, td, read, write,
invoke, observe, subscribe). click lives only in `cli` packages."""
