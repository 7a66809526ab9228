"""Example RApp ``hello``: its task class lives in `hello.task`."""
