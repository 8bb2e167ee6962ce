"""Run a benchmark script against another git ref's omnibench, for before/after figures in one run.

The ref is checked out as a temporary detached worktree and put first on PYTHONPATH; the script
(this checkout's) writes its results with --json, which are returned.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]


def results_at(ref: str, script: Path, args: list[str]) -> Any:
    """`script args --json FILE` run with git ref `ref`'s omnibench; the JSON it wrote."""
    with tempfile.TemporaryDirectory() as tmp:
        tree = Path(tmp) / "tree"
        subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", str(tree), ref], check=True,
                       capture_output=True)
        try:
            out = Path(tmp) / "before.json"
            env = {**os.environ, "PYTHONPATH": str(tree)}
            subprocess.run([sys.executable, str(script), *args, "--json", str(out)], env=env, check=True,
                           stdout=subprocess.DEVNULL)
            return json.loads(out.read_text())
        finally:
            subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(tree)], check=False,
                           capture_output=True)


def without_option(argv: list[str], option: str) -> list[str]:
    """argv without `option` and its value (as '--opt v' or '--opt=v'): the arguments to pass on to
    the same script at another ref."""
    out, skip = [], False
    for a in argv:
        if skip:
            skip = False
        elif a == option:
            skip = True
        elif not a.startswith(option + "="):
            out.append(a)
    return out
