"""The console-script plumbing: a closed output pipe ends the command quietly."""

from __future__ import annotations

import subprocess
import sys

SCRIPT = """
import argparse
from tlssim.clitools import run_main

def talk(args):
    for i in range(200000):
        print("line", i)

parser = argparse.ArgumentParser(prog="demo")
parser.set_defaults(func=talk)
raise SystemExit(run_main(parser, []))
"""


def test_closed_pipe_stops_quietly():
    """Like ``demo | head -1``: the reader leaves after one line; no traceback, status 141."""
    proc = subprocess.Popen([sys.executable, "-c", SCRIPT], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    first = proc.stdout.readline()
    proc.stdout.close()
    stderr = proc.stderr.read().decode()
    assert proc.wait(timeout=60) == 141
    assert first == b"line 0\n"
    assert "Traceback" not in stderr and "BrokenPipe" not in stderr
