"""g(v), the seconds a PU is busy after emptying a container (paper eq. 2), and the options of the
package's compiled functions.

The one definition of g(v) that the config's validation (the longest PU time of a container), the
plant's bounds and the compiled step all call; it sits below both the config and the core, which
import it from here.
"""

from __future__ import annotations

import math

import numba

#: The compiled functions are cached on disk: a new process loads them instead of recompiling.
#: ``error_model="numpy"``: a division by zero gives inf instead of raising. No divisor here can be
#: zero (v_max, product sizes and reward widths are validated ≥ 1e-3 by the config), and without the
#: exception paths numba can drop its reference counting from the step (14 % of a one-simulation
#: kernel call, ``benchmarks/kernel.py``).
JIT_OPTIONS = {"cache": True, "error_model": "numpy"}
jit = numba.njit(**JIT_OPTIONS)


@jit
def pu_time_s(volume: float, offset_s: float, time_per_product_s: float, product_size: float) -> float:
    """g(v) = β + λ·⌊v / b⌋: seconds a PU is busy after emptying a container at ``volume`` (paper
    eq. 2), for its offset β, time per product λ and product size b."""
    return offset_s + time_per_product_s * math.floor(volume / product_size)
