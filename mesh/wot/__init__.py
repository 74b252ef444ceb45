"""Protocol-neutral WoT: the TD model, input validation, problems, JSON payload decoding."""
