"""The command line: argument parsing, commands, progress reporting, doctor, Ctrl-C."""
