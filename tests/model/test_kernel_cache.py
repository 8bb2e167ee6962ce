"""The first run on a machine computes what every later run computes: the process that finds
numba's cache cold has the kernel compiled in a child and runs the cached code, like the rest.

Before, the process that compiled the kernel itself got other last bits (on a clean campaign's
runs 29 of 428 predictions moved by up to 2.6e-15 relative), so the first `omnibench fit` on a
machine wrote a model file whose last digits a re-run did not reproduce."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np

from omnibench.model import kernel

# Ground runs under several parameter sets, every state recorded every step: what a fit's
# predictions are made of (the lateral runs' roller slip and the sweep were where bits moved).
SIMULATE = """
import sys
import numpy as np
from omnibench.model import Scenario, default_robot, simulate_batch
from omnibench.model import kernel

base = default_robot()
robots = [base.replace(b=base.b * s, b_r=base.b_r * (2 - s)) for s in np.linspace(0.9, 1.1, 10)]
t_cmd = np.array([0.0, 0.4, 0.8, 1.2])
u = np.array([[0.5, -0.5, -0.5, 0.5], [0.3, 0.6, 0.6, 0.3], [-0.4, 0.4, 0.4, -0.4], [0.0, 0.0, 0.0, 0.0]])
out = [simulate_batch(robots, Scenario(mode=mode, payload=2.0 if mode == "ground" else 0.0), t_cmd, u, 1.6,
                      adaptive=True).array for mode in ("ground", "upside_down")]
np.save(sys.argv[1], np.concatenate([a.ravel() for a in out]))
mod = kernel.load_kernel()
print(len(mod.run.stats.cache_misses) + len(mod.run_serial.stats.cache_misses))
"""


def _simulate(cache: Path, out: Path) -> int:
    """Run SIMULATE in a fresh Python with numba's cache in `cache`; the compiles it did itself."""
    env = dict(os.environ, OMNIBENCH_CACHE=str(cache), NUMBA_NUM_THREADS="1")
    env.pop("NUMBA_CACHE_DIR", None)  # numba's cache beside the kernel, in `cache`
    done = subprocess.run([sys.executable, "-c", SIMULATE, str(out)], env=env, capture_output=True, text=True,
                          timeout=900, check=False)
    assert done.returncode == 0, done.stderr[-2000:]
    return int(done.stdout.split()[-1])


def test_a_cold_cache_gives_the_numbers_of_a_warm_one_bit_for_bit(tmp_path) -> None:
    cache = tmp_path / "cache"
    cold_compiles = _simulate(cache, tmp_path / "cold.npy")  # compiles (in its child), then loads
    warm_compiles = _simulate(cache, tmp_path / "warm.npy")  # loads
    assert cold_compiles == 0 and warm_compiles == 0  # neither process ran code it compiled itself
    assert any((cache / "kernels" / "__pycache__").glob("omnibench_kernel_*.run-*.nbi"))
    cold, warm = np.load(tmp_path / "cold.npy"), np.load(tmp_path / "warm.npy")
    assert cold.size > 100_000 and np.isfinite(cold).all()
    assert np.array_equal(cold, warm)


def _compile_recorded(tmp_path: Path, monkeypatch, cached: list[bool], child_ok: bool) -> tuple[list, list, object]:
    """kernel._compile of a stand-in module with the disk cache answering `cached` in turn and the
    child's compile succeeding or not: (paths the child was asked to compile, modules compiled here, module)."""
    answers = iter(cached)
    monkeypatch.setattr(kernel, "_cached_on_disk", lambda module: next(answers))
    tried: list[Path] = []
    monkeypatch.setattr(kernel, "_compile_in_child", lambda path: tried.append(path) or child_ok)
    compiled: list[object] = []
    monkeypatch.setattr(kernel, "_compile_here", compiled.append)
    module = type(sys)("omnibench_kernel_test")
    module.__file__ = str(tmp_path / "omnibench_kernel_test.py")
    kernel._compile(module)
    return tried, compiled, module


def test_a_kernel_the_child_cannot_compile_is_compiled_here(tmp_path, monkeypatch) -> None:
    """A term registered only in this process: the child fails, the compile happens here."""
    tried, compiled, module = _compile_recorded(tmp_path, monkeypatch, [False, False], child_ok=False)
    assert tried == [Path(module.__file__)] and compiled == [module]


def test_a_process_that_waited_for_the_compile_lock_loads_what_the_holder_compiled(tmp_path, monkeypatch) -> None:
    """Test workers (or a campaign and its simulated board) on a cold cache: one compiles, the
    others wait on the lock, find the kernel cached and do not compile it again."""
    # cold when first looked at, cached once the lock is ours
    tried, compiled, module = _compile_recorded(tmp_path, monkeypatch, [False, True], child_ok=True)
    assert tried == [] and compiled == [module]
    assert (tmp_path / ".compile.lock").exists()


HOLD = """
import sys, time
from pathlib import Path
from omnibench.locks import waiting_lock
with waiting_lock(sys.argv[1]):
    print("holding", flush=True)
    time.sleep(1.0)
    Path(sys.argv[2]).write_text("done")
"""


def test_the_compile_lock_waits_for_its_holder(tmp_path) -> None:
    from omnibench.locks import waiting_lock

    lock, done = tmp_path / ".compile.lock", tmp_path / "done"
    holder = subprocess.Popen([sys.executable, "-c", HOLD, str(lock), str(done)], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout is not None and holder.stdout.readline().strip() == "holding"
        with waiting_lock(lock):
            assert done.read_text() == "done"  # the holder finished its work before we got the lock
    finally:
        holder.wait(timeout=30)


class _Terminal:
    """A stderr that says whether it is a terminal, and keeps what is written."""

    def __init__(self, tty: bool) -> None:
        self.tty, self.text = tty, ""

    def isatty(self) -> bool:
        return self.tty

    def write(self, s: str) -> int:
        self.text += s
        return len(s)

    def flush(self) -> None:
        pass


def test_a_person_at_a_terminal_is_told_the_kernel_is_compiling_a_pipe_is_not(tmp_path, monkeypatch) -> None:
    for tty in (True, False):
        err = _Terminal(tty)
        monkeypatch.setattr(sys, "stderr", err)
        _compile_recorded(tmp_path, monkeypatch, [False, False], child_ok=True)
        assert (err.text == kernel.COMPILING + "\n") is tty, err.text
    err = _Terminal(True)
    monkeypatch.setattr(sys, "stderr", err)
    _compile_recorded(tmp_path, monkeypatch, [True], child_ok=True)  # cached: nothing to say
    assert err.text == ""


def test_the_cache_is_looked_up_where_numba_keeps_it(tmp_path) -> None:
    """Through numba's own index: an entry for this signature, CPU and source, not just a file."""
    module = kernel.load_kernel()  # compiled or loaded: in numba's cache now
    assert kernel._cached_on_disk(module)
    stem = Path(module.__file__).stem
    cached = Path(module.run._cache._cache_path)
    source = Path(module.__file__).read_text()

    def copy_of(text: str, folder: str, with_cache: bool):
        """The generated file with `text` in a new folder (numba's files beside it if with_cache)."""
        where = tmp_path / folder
        where.mkdir()
        (where / f"{stem}.py").write_text(text)
        copy = kernel._exec_generated(where / f"{stem}.py")
        if with_cache:
            target = Path(copy.run._cache._cache_path)
            target.mkdir(parents=True, exist_ok=True)
            for f in cached.glob(f"{stem}.*"):
                (target / f.name).write_bytes(f.read_bytes())
        return copy

    try:
        assert not kernel._cached_on_disk(copy_of(source, "empty", with_cache=False))  # nothing there
        assert kernel._cached_on_disk(copy_of(source, "same", with_cache=True))  # numba's files, same source
        # numba's files of another source: its index does not hold this one (a file is not enough)
        assert not kernel._cached_on_disk(copy_of(source + "\n# changed\n", "stale", with_cache=True))
    finally:
        sys.modules[stem] = module  # _exec_generated registered the copies under the same name
