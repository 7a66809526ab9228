"""Facts of sound that the house's simulation (robots/) and the listener (hearing/) share, in a module
that imports nothing: a render process builds a NAO's body (robots/nao.py, its microphones) without
the signal processing's SciPy (~65 MB and 1 s of imports there)."""

SPEED_OF_SOUND = 343.0  # m/s, in air at 20 deg C
