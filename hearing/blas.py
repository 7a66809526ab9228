"""One BLAS thread per process (called when `hearing` is imported, and so `robots` too; child
processes inherit it).

OpenBLAS hands a matrix product to its own worker threads and spins until they finish. A CI run
hung so for minutes: the Core's voice detector (hearing/bands.py, a 348x257 by 257x16 product on
the event loop) waited in exec_blas for a BLAS worker that slept, while executor threads of the same
process did numpy work too (numpy issue 17752 reports such hangs with several calling threads). Our
products are small and our processes many on few cores: BLAS's own threads gain nothing here.

Set before a BLAS library loads, OPENBLAS_NUM_THREADS applies to it (numpy, scipy and OpenCV each
bundle one) and to every child process; one already loaded is limited through threadpoolctl. A
value the user set is kept.
"""
from __future__ import annotations

import os

VARIABLE = "OPENBLAS_NUM_THREADS"


def one_blas_thread() -> None:
    if VARIABLE in os.environ:
        return  # the user's choice
    os.environ[VARIABLE] = "1"
    from threadpoolctl import threadpool_limits

    threadpool_limits(1, user_api="blas")
