"""Allow ``python -m mkflight``."""

from mkflight.cli import main

raise SystemExit(main())
