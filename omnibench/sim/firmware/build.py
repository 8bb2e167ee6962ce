"""Find the firmware sources and the tools that build and run them; build with make.

Every caller that needs a tool asks `missing_tools()` first, so a machine without the AVR
toolchain or simavr gets one clear line naming what to install, never a traceback.
"""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

from omnibench.errors import UserError

FIRMWARE_DIR = Path(__file__).resolve().parents[3] / "firmware"
APT_PACKAGES = "gcc-avr avr-libc binutils-avr simavr libsimavr-dev libelf-dev pkg-config make clang libclang-rt-14-dev"

#: what each purpose needs: programs on PATH and files (headers / libraries)
_NEEDS = {
    "host": (["make", "cc", "python3"], []),
    "avr": (["make", "avr-gcc", "avr-objcopy", "avr-size", "python3"], []),
    "fil": (["make", "cc", "pkg-config"], ["/usr/include/simavr/sim_avr.h", "/usr/include/libelf.h"]),
    "fuzz": (["make", "clang", "python3"], []),
}


def _fuzzer_runtime_missing() -> bool:
    """True when clang is present but its libFuzzer runtime (libclang-rt-*-dev) is not."""
    clang = shutil.which("clang")
    if clang is None:
        return False
    r = subprocess.run([clang, "-print-runtime-dir"], capture_output=True, text=True)
    folder = Path(r.stdout.strip())
    return r.returncode != 0 or not any(folder.glob("libclang_rt.fuzzer-*.a"))


def missing_tools(*purposes: str) -> list[str]:
    """Names of the programs / headers the given purposes ("host", "avr", "fil", "fuzz") lack."""
    missing: list[str] = []
    for p in purposes:
        progs, files = _NEEDS[p]
        missing += [x for x in progs if shutil.which(x) is None and x not in missing]
        missing += [Path(f).name for f in files if not Path(f).exists() and Path(f).name not in missing]
    if "fuzz" in purposes and _fuzzer_runtime_missing():
        missing.append("clang's libFuzzer runtime (libclang-rt-14-dev)")
    if not FIRMWARE_DIR.is_dir():
        missing.append("firmware/ sources (a source checkout)")
    return missing


def require(*purposes: str) -> None:
    """UserError naming the missing tools and the Debian packages that bring them."""
    miss = missing_tools(*purposes)
    if miss:
        raise UserError(f"firmware tools missing: {', '.join(miss)} (apt-get install {APT_PACKAGES})")


def make(target: str = "all", build: Path | None = None, **settings: str) -> Path:
    """`make -C firmware TARGET [BUILD=...] [SETTING=value ...]`; returns the build folder."""
    build = Path(build) if build else FIRMWARE_DIR / "build"
    args = ["make", "-s", "-C", str(FIRMWARE_DIR), target, f"BUILD={build}"]
    args += [f"{k}={v}" for k, v in settings.items()]
    r = subprocess.run(args, capture_output=True, text=True)
    if r.returncode != 0:
        raise UserError(f"firmware build failed (make {target}): {(r.stderr or r.stdout).strip()[-600:]}")
    return build
