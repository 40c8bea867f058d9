"""numpy's PCG64 generator, compiled (numba): a copy-axis world draws each copy's numbers inside its kernels, from
the copy's own generator state, instead of calling every copy's ``numpy.random.Generator`` from Python.

A state is six uint64 (``STATE_WORDS``): the 128-bit LCG state and increment (high word first), then numpy's
buffer of a 32-bit half (``has_uint32``, ``uinteger``). :func:`state_of` and :func:`set_state` move it from and into a
``Generator``. The draws are numpy's, bit for bit, and leave the state where numpy leaves it:

* :func:`next_uint64` is ``pcg64_random_r``: the LCG step (multiplier 0x2360ED051FC65DA44385DF649FCCF645), then the
  XSL-RR output of the new state;
* :func:`random_fill` is ``Generator.random``: ``(next_uint64 >> 11) · 2^−53`` per number;
* :func:`integers_fill` is ``Generator.integers(low, high)`` (int64) for ``high − low − 1`` below 2^32 − 1: Lemire's
  bounded draw on 32-bit halves (``buffered_bounded_lemire_uint32``), whose unused half numpy keeps for the next one.

:func:`draw_integers` draws from either: a state of this module, or a ``numpy.random.Generator`` handed to compiled code
(numba's own ``Generator.integers``, which is numpy's for every bit generator and advances the caller's object).

``tests/core/test_pcg64.py`` compares them with numpy over interleaved draws of every kind, states included.
"""

from __future__ import annotations

import numba
import numpy as np
from llvmlite import ir
from numba.core import types
from numba.extending import intrinsic, overload

from mrcomm_env.core.backend import configure_numba_cache

configure_numba_cache()  # before the @njit(cache=True) below: never cache into the package

STATE_WORDS = 6  # state high, state low, increment high, increment low, has_uint32, uinteger
_MULT_HIGH = np.uint64(2549297995355413924)
_MULT_LOW = np.uint64(4865540595714422341)
_LOW32 = np.uint64(0xFFFFFFFF)
_32 = np.uint64(32)
_64_MASK = (1 << 64) - 1


def state_of(generator: np.random.Generator, out: np.ndarray) -> None:
    """Write ``generator``'s PCG64 state into ``out`` (``STATE_WORDS`` uint64)."""
    state = generator.bit_generator.state
    if state["bit_generator"] != "PCG64":
        raise ValueError(f"a compiled draw needs a PCG64 generator, got {state['bit_generator']}")
    lcg, inc = state["state"]["state"], state["state"]["inc"]
    out[:] = (lcg >> 64, lcg & _64_MASK, inc >> 64, inc & _64_MASK, state["has_uint32"], state["uinteger"])


def set_state(generator: np.random.Generator, words: np.ndarray) -> None:
    """Put the state ``words`` (``STATE_WORDS`` uint64, from :func:`state_of` and compiled draws) into ``generator``."""
    high, low, inc_high, inc_low, has_uint32, uinteger = (int(w) for w in words)
    generator.bit_generator.state = {
        "bit_generator": "PCG64",
        "state": {"state": (high << 64) | low, "inc": (inc_high << 64) | inc_low},
        "has_uint32": has_uint32,
        "uinteger": uinteger,
    }


@intrinsic
def _mul_high(typingctx, a, b):
    """The high 64 bits of the 128-bit product of two uint64 (one machine multiply, as numpy's 128-bit LCG does)."""
    if a != types.uint64 or b != types.uint64:
        return None

    def codegen(context, builder, signature, args):
        wide = ir.IntType(128)
        product = builder.mul(builder.zext(args[0], wide), builder.zext(args[1], wide))
        return builder.trunc(builder.lshr(product, ir.Constant(wide, 64)), ir.IntType(64))

    return types.uint64(types.uint64, types.uint64), codegen


@numba.njit(cache=True)
def next_uint64(state):
    """``pcg64_random_r``: state ← state · multiplier + increment (mod 2^128), then rotr64(high ⊕ low, state >> 122)."""
    high, low = state[0], state[1]
    product_low = low * _MULT_LOW  # uint64 products wrap: the low 64 bits
    product_high = _mul_high(low, _MULT_LOW) + low * _MULT_HIGH + high * _MULT_LOW
    new_low = product_low + state[3]
    carry = np.uint64(1) if new_low < product_low else np.uint64(0)
    new_high = product_high + state[2] + carry
    state[0], state[1] = new_high, new_low
    value = new_high ^ new_low
    rot = new_high >> np.uint64(58)
    return (value >> rot) | (value << ((np.uint64(64) - rot) & np.uint64(63)))


@numba.njit(cache=True)
def next_uint32(state):
    """``pcg64_next32``: the kept high half of the last 64-bit output, or the low half of a new one."""
    if state[4]:
        state[4] = np.uint64(0)
        return state[5]
    value = next_uint64(state)
    state[4] = np.uint64(1)
    state[5] = value >> _32
    return value & _LOW32


@numba.njit(cache=True)
def random_fill(state, out):
    """``Generator.random(out=out)`` for a 1-d float64 ``out``."""
    for i in range(out.size):
        out[i] = np.float64(next_uint64(state) >> np.uint64(11)) * (1.0 / 9007199254740992.0)


@numba.njit(cache=True)
def integers_fill(state, low, high, out):
    """``Generator.integers(low, high, size=out.size)`` into the int64 ``out``, for 0 < high − low ≤ 2^32 − 1
    (``random_bounded_uint64_fill`` with a 32-bit range: ``buffered_bounded_lemire_uint32``)."""
    span = np.uint64(high - low - 1)  # numpy's rng, the largest offset
    if span == np.uint64(0):
        for i in range(out.size):
            out[i] = low
        return
    bound = span + np.uint64(1)
    threshold = (_LOW32 - span) % bound
    for i in range(out.size):
        m = next_uint32(state) * bound
        leftover = m & _LOW32
        if leftover < bound:
            while leftover < threshold:
                m = next_uint32(state) * bound
                leftover = m & _LOW32
        out[i] = low + np.int64(m >> _32)


def draw_integers(source, low, high, out):
    """``Generator.integers(low, high, size=out.size)`` into the int64 ``out``, from ``source``: a state of this module
    (:func:`integers_fill`, for 0 < high − low ≤ 2^32 − 1) or a ``numpy.random.Generator`` of any bit generator. Called
    from compiled code only, which chooses by the type of ``source`` when it compiles."""
    raise TypeError("draw_integers is called from compiled code only")


@overload(draw_integers)
def _draw_integers(source, low, high, out):
    if isinstance(source, types.Array):

        def from_state(source, low, high, out):
            integers_fill(source, low, high, out)

        return from_state
    if isinstance(source, types.NumPyRandomGeneratorType):

        def from_generator(source, low, high, out):
            out[:] = source.integers(low, high, out.size)

        return from_generator
    return None
