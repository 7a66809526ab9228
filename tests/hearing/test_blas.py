"""hearing/blas.py: importing `hearing` (the Core, the Platform's speech service) or `robots` (which
imports it) leaves every loaded BLAS library with one thread."""
from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

PROBE = """
import json, os, numpy
import {package}, scipy.linalg, threadpoolctl
print(json.dumps([os.environ.get("OPENBLAS_NUM_THREADS"),
                  sorted({{i["num_threads"] for i in threadpoolctl.threadpool_info() if i["user_api"] == "blas"}})]))
"""


def _probe(package: str, **env) -> list:
    clean = {k: v for k, v in os.environ.items() if k != "OPENBLAS_NUM_THREADS"}
    out = subprocess.run([sys.executable, "-c", PROBE.format(package=package)], env={**clean, **env},
                         capture_output=True, text=True, timeout=120, check=True).stdout
    return json.loads(out.strip().splitlines()[-1])


@pytest.mark.parametrize("package", ["hearing", "robots"])
def test_importing_limits_blas_to_one_thread_even_when_numpy_came_first(package):
    assert _probe(package) == ["1", [1]]


def test_a_thread_count_the_user_set_is_kept():
    variable, counts = _probe("hearing", OPENBLAS_NUM_THREADS="2")
    assert variable == "2" and 2 in counts
