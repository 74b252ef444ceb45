"""tdgen's command-line commands: `tdgen`, `check`, `ik`."""
