"""Generate and compile lane-vectorised numba kernels for many small matrices at once.

Why this exists: the estimator runs about a thousand 16-state Kalman filters per
sample. Written as ordinary loops, numba (LLVM) cannot prove that the small arrays do
not alias, and its SLP vectoriser is off by default, so the work stays scalar
(about 2 GFLOP/s here). The kernels are therefore written for a **lane layout**:
particle ``p`` lives in chunk ``p // LANES`` and lane ``p % LANES``, every matrix
element is a run of ``LANES`` contiguous doubles, and the generated source spells the
lanes out as scalar locals (``a_0 ... a_7``). LLVM's SLP vectoriser then packs them
into AVX registers (measured: 14-29 GFLOP/s per core for the blocked 16x16 product).

Layout of a batch of matrices, shape ``(n_chunks, n * n * LANES)``: element ``(i, j)``
of particle ``(ch, l)`` is at ``[ch, (i * n + j) * LANES + l]``; vectors ``(n_chunks,
n * LANES)`` at ``[ch, i * LANES + l]``.

Threads: the kernels run ``prange`` over chunks; the threading layer and the thread
count are set once per process by :mod:`gateway.estimator.threads`, not here.

Compilation: the source is compiled with this package's file name and a name that
carries a hash of the generated text, so numba's on-disk cache works and is
invalidated whenever the generated code changes. SLP vectorisation is switched on only
while these kernels compile (``numba.config.SLP_VECTORIZE``), never globally. A kernel
compiles on its first call, not at import (:class:`Kernel`), so that
:mod:`gateway.estimator.precompile` can compile them in parallel processes.

Every kernel is one ``for ch in prange(nch):`` loop over chunks. numba's parfor passes
(copy propagation, reaching definitions) grow much faster than linearly with the size
of that loop's body: the doubling kernel's 2,400-line body took 281 s of them. Such a
kernel is therefore compiled with its body as a separate, serial function of one chunk
(:func:`split_chunk_loop`), which the ``prange`` loop calls: 60 s (measured
2026-11-25). The arithmetic, and so every result, is the same either way.
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

import numba
import numpy as np

LANES = 8
"""Particles per chunk (one AVX-512 register of doubles, two AVX2 registers)."""


def lanes(expr: str) -> list[str]:
    """Expand a template with ``{l}`` into one string per lane."""
    return [expr.format(l=lane) for lane in range(LANES)]


def stmt(indent: int, template: str) -> list[str]:
    """One statement per lane, indented by ``indent`` levels."""
    pad = "    " * indent
    return [pad + s for s in lanes(template)]


def block_product(indent: int, *, a: str, a_row: str, b: str, b_row: str, n: int,
                  bi: int, bj: int, init: str | None, out: list[tuple[str, str]],
                  guard: str | None = None) -> list[str]:
    """Register-blocked ``out[i, j] = init[i, j] + sum_k a[i, k] * b'[j, k]`` lines.

    ``a_row(r)``/``b_row(r)`` are templates giving the flat offset of element (r, k)
    of the left/right operand (with ``{r}`` and ``k`` free); the block rows are
    ``ib + 0..bi-1`` and columns ``jb + 0..bj-1`` (loop variables set by the caller).
    For ``b`` in row layout (``b[k, j]``) pass a template for (k, j) via ``b_row`` using
    ``{r}`` as j. ``init`` is a template for the initial value of (i, j) with ``{i}``,
    ``{j}`` or None for zero. ``out`` is a list of (array, offset template with
    ``{i}``, ``{j}``) pairs that receive each result; ``guard`` an optional condition
    template on ``{i}``, ``{j}`` for writing.
    """
    pad = "    " * indent
    lines: list[str] = []
    for p in range(bi):
        for q in range(bj):
            i, j = f"(ib + {p})", f"(jb + {q})"
            for lane in range(LANES):
                start = "0.0" if init is None else init.format(i=i, j=j, l=lane)
                lines.append(f"{pad}c_{p}_{q}_{lane} = {start}")
    lines.append(f"{pad}for k in range({n}):")
    inner = pad + "    "
    for p in range(bi):
        off = a_row.format(r=f"(ib + {p})")
        for lane in range(LANES):
            lines.append(f"{inner}u_{p}_{lane} = {a}[{off} + {lane}]")
    for q in range(bj):
        off = b_row.format(r=f"(jb + {q})")
        for lane in range(LANES):
            lines.append(f"{inner}w_{q}_{lane} = {b}[{off} + {lane}]")
    for p in range(bi):
        for q in range(bj):
            for lane in range(LANES):
                lines.append(f"{inner}c_{p}_{q}_{lane} += u_{p}_{lane} * w_{q}_{lane}")
    for p in range(bi):
        for q in range(bj):
            i, j = f"(ib + {p})", f"(jb + {q})"
            body = []
            for arr, tmpl in out:
                off = tmpl.format(i=i, j=j)
                body += [f"{arr}[{off} + {lane}] = c_{p}_{q}_{lane}" for lane in range(LANES)]
            if guard is None:
                lines += [pad + s for s in body]
            else:
                lines.append(f"{pad}if {guard.format(i=i, j=j)}:")
                lines += [pad + "    " + s for s in body]
    return lines


@contextmanager
def _slp_enabled() -> Iterator[None]:
    cfg: Any = numba.config
    saved = cfg.SLP_VECTORIZE
    cfg.SLP_VECTORIZE = 1
    try:
        yield
    finally:
        cfg.SLP_VECTORIZE = saved


class Kernel:
    """A generated kernel, compiled (or loaded from numba's cache) on its first call or by
    :meth:`compile`; :data:`KERNELS` lists every one by name."""

    def __init__(self, name: str, build: Callable[[], Callable[..., Any]]) -> None:
        self.name = name
        self._build = build
        self._func: Callable[..., Any] | None = None

    def compile(self) -> Callable[..., Any]:
        """The compiled function (compiled or loaded now if not yet)."""
        if self._func is None:
            self._func = self._build()
        return self._func

    def __call__(self, *args: Any) -> Any:
        return (self._func or self.compile())(*args)


KERNELS: dict[str, Kernel] = {}
"""Every kernel made by :func:`compile_kernel` in this process, by ``module.name``."""


_OPTIONS: dict[str, Any] = {"cache": True, "fastmath": {"contract"}, "nogil": True}
"""numba options of every kernel function."""
_CHUNK_OPTIONS: dict[str, Any] = {"error_model": "numpy"}
"""And of a chunk function: numpy's error model, which numba gives a prange body too (a
division by zero gives inf or nan, which the kernels test for, with no branch around
every division)."""

PRANGE_LINE = "    for ch in prange(nch):"
"""The one chunk loop every generated kernel has, at the top level of its body."""


def split_chunk_loop(lines: list[str], name: str, chunk_name: str) -> tuple[list[str],
                                                                            list[str]]:
    """A kernel's source as (outer, chunk): ``chunk_name(<args>, ch)`` runs the body of
    the kernel's ``prange`` loop for chunk ``ch``, after the same preamble (shape reads),
    and the outer ``name`` keeps the preamble and the loop, which now only calls it.

    Expects ``def name(<args>):``, preamble lines, :data:`PRANGE_LINE`, and the body
    indented below it to the end; anything else is a generator bug (ValueError).
    """
    head = f"def {name}("
    if not lines or not lines[0].startswith(head) or not lines[0].endswith("):"):
        raise ValueError(f"expected a kernel source starting 'def {name}(...):', "
                         f"got {lines[0] if lines else 'nothing'!r}")
    args = lines[0][len(head):-2]
    if lines.count(PRANGE_LINE) != 1:
        raise ValueError(f"expected one {PRANGE_LINE.strip()!r} in kernel {name}, "
                         f"got {lines.count(PRANGE_LINE)}")
    at = lines.index(PRANGE_LINE)
    preamble, body = lines[1:at], lines[at + 1:]
    stray = [b for b in body if b.strip() and not b.startswith("        ")]
    if stray:
        raise ValueError(f"expected kernel {name}'s loop body to run to its end, "
                         f"got {stray[0]!r} after it")
    chunk = [f"def {chunk_name}({args}, ch):", *preamble, *(b[4:] for b in body)]
    outer = [lines[0], *preamble, PRANGE_LINE, f"        {chunk_name}({args}, ch)"]
    return outer, chunk


def _chunk_signature(signature: str) -> str:
    """``void(<types>)`` of a kernel as that of its chunk function: ``void(<types>, i8)``."""
    if not (signature.startswith("void(") and signature.endswith(")")):
        raise ValueError(f"expected a kernel signature 'void(...)', got {signature!r}")
    return signature[:-1] + ", i8)"


def compile_kernel(name: str, lines: list[str], signature: str, *, module: str,
                   source_file: str, parallel: bool, chunk_function: bool = False,
                   env: dict[str, Any] | None = None) -> Kernel:
    """Generated source ``lines`` (a ``def name(...)`` whose body is one ``prange`` loop
    over chunks) as a :class:`Kernel`, which numba compiles (cached on disk) on its first
    call, not at import: so that :mod:`gateway.estimator.precompile` can compile the
    kernels in parallel processes.

    ``chunk_function``: the loop body becomes a serial function of one chunk
    (:func:`split_chunk_loop`), which compiles in a fraction of the time (module
    docstring) but runs 3-9 % slower (measured on one thread, 2026-11-25: numba marks
    a prange body's arrays as not aliased, and a function's it cannot). For the large,
    rarely called doubling kernel, not for the per-sample ones.

    The function(s) get names suffixed with a hash of the source as compiled and its
    options, and ``source_file`` as their file name, so numba's cache keys on both;
    ``module`` is the importable module that numba re-imports when it loads the cached
    code. ``fastmath`` is limited to FMA contraction (no reassociation: sums keep their
    order, results stay deterministic).
    """
    chunk: list[str] = []
    outer = lines
    if chunk_function:
        outer, chunk = split_chunk_loop(lines, name, f"{name}_chunk")
    text = "\n".join(chunk) + "\n\n\n" + "\n".join(outer) + "\n"
    # the compile options are part of what is cached: a change of them renames too
    recipe = f"{text}\n{signature}\nparallel={parallel}\n{_CHUNK_OPTIONS}\n{_OPTIONS}"
    digest = hashlib.sha1(recipe.encode()).hexdigest()[:12]
    unique, chunk_unique = f"{name}_{digest}", f"{name}_chunk_{digest}"
    text = text.replace(f"{name}_chunk(", f"{chunk_unique}(").replace(
        f"def {name}(", f"def {unique}(", 1)

    def build() -> Callable[..., Any]:
        namespace: dict[str, Any] = {"np": np, "prange": numba.prange, "__name__": module}
        namespace.update(env or {})
        exec(compile(text, source_file, "exec"), namespace)  # noqa: S102 - generated, no input
        with _slp_enabled():
            if chunk_function:
                namespace[chunk_unique] = numba.njit(_chunk_signature(signature), **_OPTIONS,
                                                     **_CHUNK_OPTIONS)(namespace[chunk_unique])
            return numba.njit(signature, parallel=parallel, **_OPTIONS)(namespace[unique])

    kernel = Kernel(f"{module}.{name}", build)
    KERNELS[kernel.name] = kernel
    return kernel


def compile_all() -> None:
    """Compile (or load from the cache) every kernel of :data:`KERNELS`."""
    for kernel in KERNELS.values():
        kernel.compile()
