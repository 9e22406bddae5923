"""The ``depotbench`` command line: argument parsing and printing over the library, one
module per group of commands. Nothing outside this package imports it."""
