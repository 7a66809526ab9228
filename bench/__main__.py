"""python -m bench [--quick] [--json FILE] [--only NAME ...]  (see bench/runner.py)"""
import faulthandler
import sys

from .runner import main

faulthandler.enable()  # a native crash (a library's heap corruption) prints every thread's stack

sys.exit(main())
