"""The `rapp` command line: the top floor, beside scenarios and bench (see docs/architecture.md)."""
