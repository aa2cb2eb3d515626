"""Command implementations: one typed ``cmd_*() -> int`` per CLI subcommand."""
