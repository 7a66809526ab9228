"""python -m bench [--quick] [--json FILE] [--only NAME ...]  (see bench/runner.py)"""
import sys

from .runner import main

sys.exit(main())
