"""Task of the ``hello`` example RApp (placeholder until the SDK base class exists in rapps/sdk.py)."""


class HelloTask:
    """Says the configured greeting through the robot's communication API, then finishes."""

    async def run(self):
        """Run the task once; the Dynamic Agent runtime awaits this coroutine."""
        return None
