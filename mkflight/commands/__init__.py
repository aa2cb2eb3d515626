"""The CLI's commands: per group an ``add_parser``, per subcommand a typed ``cmd_*() -> int``."""
