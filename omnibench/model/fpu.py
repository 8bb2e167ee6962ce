"""Subnormal floats off inside the integrator kernel (flush-to-zero, denormals-are-zero).

A speed that decays towards zero (a robot coasting to rest, a roller's slip settling, a
regularised sign's slope sech^2 far from zero) passes through subnormal doubles (below
2.2e-308), and x86 arithmetic on those takes a microcode assist of ~100 cycles per operation.
On the clean campaign's energy runs that was 4/5 of the kernel's time (issue 34: the four runs
under one parameter set, one thread, 1.20 -> 0.25 s CPU). A number below 2.2e-308 is zero for
every quantity the model computes (its smallest physical scale, a 1e-9 rad/s sign width, is 300
orders above), so the kernel runs with the SSE control register's FTZ and DAZ bits set, per
lane group and on the thread that runs it, and puts the register back after: nothing outside
the kernel sees the change. The model's results do not move (the clean campaign's fit: the same
model file; tests/model/test_kernel_numerics.py: the closed forms, the energy balance and the
plain numpy model as before, and no subnormal recorded).

Only on x86-64 (the MXCSR register); elsewhere both functions do nothing.
"""

from __future__ import annotations

import platform

from llvmlite import ir
from numba import njit, types
from numba.core import cgutils
from numba.extending import intrinsic

#: MXCSR bits: FTZ (flush results to zero, bit 15) and DAZ (read subnormal inputs as zero, bit 6)
FTZ_DAZ = 0x8040
X86 = platform.machine().lower() in ("x86_64", "amd64")


def _mxcsr_call(builder, name: str, slot) -> None:
    fnty = ir.FunctionType(ir.VoidType(), [cgutils.voidptr_t])
    fn = cgutils.get_or_insert_function(builder.module, fnty, name)
    builder.call(fn, [builder.bitcast(slot, cgutils.voidptr_t)])


@intrinsic
def flush_subnormals(typingctx):
    """Set FTZ and DAZ on this thread; returns the previous MXCSR (int32) for `restore_fpu`
    (0 and no change off x86-64)."""

    def codegen(context, builder, signature, args):
        slot = cgutils.alloca_once(builder, ir.IntType(32))
        if not X86:
            builder.store(ir.Constant(ir.IntType(32), 0), slot)
            return builder.load(slot)
        _mxcsr_call(builder, "llvm.x86.sse.stmxcsr", slot)
        old = builder.load(slot)
        builder.store(builder.or_(old, ir.Constant(ir.IntType(32), FTZ_DAZ)), slot)
        _mxcsr_call(builder, "llvm.x86.sse.ldmxcsr", slot)
        return old

    return types.int32(), codegen


@intrinsic
def restore_fpu(typingctx, old):
    """Put back the MXCSR `flush_subnormals` returned (nothing off x86-64)."""

    def codegen(context, builder, signature, args):
        if X86:
            slot = cgutils.alloca_once(builder, ir.IntType(32))
            builder.store(args[0], slot)
            _mxcsr_call(builder, "llvm.x86.sse.ldmxcsr", slot)
        return context.get_dummy_value()

    return types.void(types.int32), codegen


@intrinsic
def _mxcsr(typingctx):

    def codegen(context, builder, signature, args):
        slot = cgutils.alloca_once(builder, ir.IntType(32))
        if X86:
            _mxcsr_call(builder, "llvm.x86.sse.stmxcsr", slot)
        else:
            builder.store(ir.Constant(ir.IntType(32), 0), slot)
        return builder.load(slot)

    return types.int32(), codegen


@njit(cache=True)
def mxcsr() -> int:
    """The MXCSR of the calling thread (0 off x86-64): for the tests."""
    return _mxcsr()  # type: ignore[call-arg]  # numba supplies typingctx
