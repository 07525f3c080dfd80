"""lanecode's compiler: a kernel's chunk loop becomes a call of a serial chunk function."""

from __future__ import annotations

import numpy as np
import pytest

from gateway.estimator import lanecode
from gateway.estimator.lanecode import PRANGE_LINE, compile_kernel, split_chunk_loop

SOURCE = ["def scaled(X, a, Y):",
          "    nch = X.shape[0]",
          "    n = X.shape[1]",
          PRANGE_LINE,
          "        s = 0.0",
          "        for i in range(n):",
          "            Y[ch, i] = a * X[ch, i] + s",
          "            s += X[ch, i]"]
"""A small kernel in the generators' shape: Y[ch, i] = a X[ch, i] + sum of X[ch, :i]."""


def test_the_loop_body_becomes_a_chunk_function_after_the_same_preamble():
    outer, chunk = split_chunk_loop(SOURCE, "scaled", "scaled_chunk")
    assert outer == ["def scaled(X, a, Y):", "    nch = X.shape[0]", "    n = X.shape[1]",
                     PRANGE_LINE, "        scaled_chunk(X, a, Y, ch)"]
    assert chunk == ["def scaled_chunk(X, a, Y, ch):", "    nch = X.shape[0]",
                     "    n = X.shape[1]", "    s = 0.0", "    for i in range(n):",
                     "        Y[ch, i] = a * X[ch, i] + s", "        s += X[ch, i]"]


@pytest.mark.parametrize(("lines", "expected"), [
    (["def other(X):", *SOURCE[1:]], "expected a kernel source starting 'def scaled(...):'"),
    ([line for line in SOURCE if line != PRANGE_LINE], "expected one 'for ch in prange(nch):'"),
    ([*SOURCE, "    return 0"], "expected kernel scaled's loop body to run to its end"),
])
def test_a_source_of_another_shape_is_refused(lines, expected):
    with pytest.raises(ValueError, match=expected.replace("(", r"\(").replace(")", r"\)")):
        split_chunk_loop(lines, "scaled", "scaled_chunk")


@pytest.mark.parametrize("chunk_function", [False, True])
def test_the_compiled_kernel_computes_what_the_source_says(chunk_function):
    kernel = compile_kernel("scaled", SOURCE, "void(f8[:, ::1], f8, f8[:, ::1])",
                            module=__name__, source_file=__file__, parallel=True,
                            chunk_function=chunk_function)
    try:
        X = np.arange(12.0).reshape(3, 4) ** 1.5
        Y = np.zeros_like(X)
        kernel(X, 2.5, Y)
        expected = 2.5 * X + np.concatenate([np.zeros((3, 1)), np.cumsum(X, axis=1)[:, :-1]],
                                            axis=1)
        np.testing.assert_allclose(Y, expected, rtol=1e-15)
    finally:
        del lanecode.KERNELS[kernel.name]
