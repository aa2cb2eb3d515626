"""The flight: the pure step (step.py); the asyncio daemon comes with `fly`."""
