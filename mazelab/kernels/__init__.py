"""Compiled kernels (numba, the `fast` extra) for the hot parts of the particle filters: the model's
equations (mazelab.kernels.model), the weights and the resampler (mazelab.kernels.weights), which
mazelab.kernels.compiled.CompiledKernels calls for a filter (mazelab.backend chooses it or numpy's).
Each takes R runs in one call and works on float32 particles, in the numpy path's float32 arithmetic
where it has some; cos, sin and exp are polynomials the compiler vectorises (mazelab.kernels.vector_math).

Threads: every kernel is one body over chunks of CHUNK particles (a run's particles split in order; a
chunk never spans two runs), compiled to run them in order and over numba's threads (`Kernel`,
`threading_layer`). The chunks, not the threads, fix everything a result depends on: the random draws
(a stream per run and call, numbered by particle: vector_math.random_bits) and the order of every sum
(partial sums per chunk, added in chunk order), so a seed gives the same run bit for bit on any number
of threads, and R runs together are R single runs.

Importing this package imports numba (a process's start-up: mazelab.backend.STARTUP_SECONDS); each
kernel is compiled on its first call and cached on disk (`Kernel`).
"""

from __future__ import annotations

import contextlib
import ctypes
import hashlib
import os
import sys
import threading
import warnings
from collections.abc import Callable
from functools import cache
from pathlib import Path
from typing import Any

import numba
from numba import types
from numba.core.caching import FunctionCache, IndexDataCacheFile
from numba.core.codegen import get_host_cpu_features
from numba.core.compiler import Compiler
from numba.core.runtime import rtsys
from numba.extending import intrinsic

CHUNK = 4096  # particles a chunk: what a thread takes at a time, and what fixes the draws' and the sums' order
# particles in a call from which it runs on the threads (benchmarks/threads.py, docs/speed.md): a pass over
# fewer takes under 0.1 ms, where a second thread's start (TBB: microseconds) and the Python around it count
THREADED_FROM = 1 << 16


def threading_layer() -> str:
    """numba's threading layer for the kernels: "tbb" where Intel's TBB library loads, else "workqueue"
    (which wakes its threads for every call and waits for the slowest: docs/speed.md, "Threads"); both
    work after a fork. The `tbb` package (the fast extra) puts the library in the environment's lib
    folder, which the loader does not search: it is loaded here by its path first, so that numba finds it."""
    for path in (Path(sys.prefix) / "lib" / "libtbb.so.12", "libtbb.so.12"):
        with contextlib.suppress(OSError, AttributeError):
            library = ctypes.CDLL(str(path), mode=ctypes.RTLD_GLOBAL)
            if library.TBB_runtime_interface_version() >= 12060:  # numba takes 2021.6 and later
                return "tbb"
    return "workqueue"


# TBB's library loaded where it is installed (for a user's choice of "tbb" too); the user's choice stands
numba.config.THREADING_LAYER = os.environ.get("NUMBA_THREADING_LAYER", threading_layer())
# 512-bit vectors where the CPU has AVX-512 (LLVM's tuning for Intel's keeps loops at 256 bits: the likelihood's pass
# 25% slower, the move's and the weights' 10%; benchmarks/pass_costs.py), the same values; the user's choice stands.
if numba.config.CPU_FEATURES is None and "+avx512f" in get_host_cpu_features().split(","):
    numba.config.CPU_FEATURES = get_host_cpu_features() + ",-prefer-256-bit"


@cache
def _warn_once(message: str) -> None:
    """One warning per process for each message (the CLI prints it as one line)."""
    warnings.warn(message, stacklevel=3)


def sources_digest(folder: Path) -> str:
    """A digest of the kernels' sources (every .py file in `folder`), 16 hex digits.

    numba keeps a cached kernel while its own file's time stamp and size are unchanged, but a kernel
    inlines helpers from the package's other modules (vector_math's cos and sin, weights' exponentials):
    an edit there alone (a `git pull`) would leave the old machine code running. Each kernel's cache
    entry is stamped with this digest too, so that any change to these files compiles them again."""
    digest = hashlib.sha256()
    for path in sorted(folder.glob("*.py")):
        digest.update(path.name.encode() + b"\0" + path.read_bytes())
    return digest.hexdigest()[:16]


_SOURCES = sources_digest(Path(__file__).parent)


class _MendingCache(FunctionCache):
    """numba's on-disk cache of one kernel, fresh only while the kernels' sources are all unchanged
    (sources_digest), that a damaged file does not stop: a file that does not load is dropped and the
    kernel compiled again (and saved over it), and a folder that cannot take the file leaves the
    kernel compiled in memory, with one warning naming the folder."""

    def __init__(self, py_func: Callable[..., Any], variant: str = ""):
        super().__init__(py_func)
        stamp = (self._cache_file._source_stamp, _SOURCES)  # numba's (time, size), and ours
        # a kernel's two compilations (in order, on the threads) in files of their own
        self._cache_file = IndexDataCacheFile(self._cache_path, self._impl.filename_base + variant, stamp)

    def load_overload(self, sig: Any, target_context: Any) -> Any:
        """The cached kernel, with numba's runtime (NRT) set up first, but not the compiler's registries
        numba refreshes before each load (some 0.15 s of imports a process: machine code loaded from the
        cache runs without them; a kernel compiled after all sets them up itself)."""
        try:
            rtsys.initialize(target_context)
            return self._load_overload(sig, target_context)
        except Exception:  # a damaged index or data file: pickle, EOF, value errors; compile again
            self._drop_index()
            return None

    def save_overload(self, sig: Any, data: Any) -> None:
        try:
            try:
                super().save_overload(sig, data)
            except OSError:
                raise
            except Exception:  # the index it adds to does not load: start it again
                self._drop_index()
                super().save_overload(sig, data)
        except OSError as error:
            _warn_once(
                f"mazelab's compiled kernels cannot be saved in {self.cache_path} ({error.strerror or error}): "
                "they are compiled again in each process; free space there, or set NUMBA_CACHE_DIR to a "
                "writable folder"
            )

    def _drop_index(self) -> None:
        """Remove this kernel's index file (its data files are then written afresh)."""
        with contextlib.suppress(OSError):
            os.unlink(self._cache_file._index_path)


class _NoAliasCompiler(Compiler):
    """numba's compiler, with the arrays a kernel takes marked as not overlapping (LLVM's noalias): a
    loop that gathers (from the lookup table, by the ancestors) vectorises only then."""

    def define_pipelines(self) -> list:
        self.state.flags.noalias = True
        return super().define_pipelines()


# a helper inlined into the kernels that call it: a function called per particle, whose call would
# otherwise count the references of every array it is passed
inline = numba.njit(inline="always", nogil=True, error_model="numpy")
_LAUNCH = threading.Lock()  # numba's workqueue takes one launch at a time


class Kernel:
    """One kernel body over chunks (`function`, its loop over them a `numba.prange`), compiled twice by
    numba in nopython mode (releasing the GIL, numpy's error model: x / 0 is inf): `serial` runs the
    chunks in order on the calling thread, `parallel` spreads them over numba's threads. Both give the
    same values, so a call takes whichever is free. Each is compiled on its first call and cached on disk
    (`_MendingCache`) where a cache folder can be written, else kept in memory (one warning a process)."""

    def __init__(self, function: Callable[..., Any]):
        self.serial, self.parallel = self._compiled(function), self._compiled(function, "-threads", parallel=True)

    @staticmethod
    def _compiled(function: Callable[..., Any], variant: str = "", **options: Any) -> Any:
        dispatcher = numba.njit(nogil=True, error_model="numpy", pipeline_class=_NoAliasCompiler, **options)(function)
        try:
            dispatcher._cache = _MendingCache(function, variant)  # what numba's cache=True sets, with the mending
        except RuntimeError:  # numba found no writable cache folder ("cannot cache function ...")
            _warn_once(
                "mazelab's compiled kernels cannot be cached (no writable cache folder; set NUMBA_CACHE_DIR): "
                "they are compiled again in each process"
            )
        return dispatcher

    def __call__(self, threads: int, particles: int, *args: Any) -> Any:
        """The kernel over `particles` particles on `threads` threads: in order here on one thread or below
        THREADED_FROM particles, else on numba's threads when they are free."""
        if threads > 1 and particles >= THREADED_FROM and _LAUNCH.acquire(blocking=False):
            try:
                numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))
                numba.set_parallel_chunksize(1)  # each chunk a task of its own: a free thread takes the next
                return self.parallel(*args)
            finally:
                _LAUNCH.release()
        return self.serial(*args)


@intrinsic
def scratch(typingctx, shape, dtype):  # pragma: no cover - compiled
    """An uninitialised C-order array of `shape` (an int or a tuple of ints) and `dtype`, np.empty's,
    allocated by numba's runtime here: np.empty's implementation (and reshape's) carry environments that
    make a kernel loaded from the cache import numba's array modules (some 25 ms of a process's start-up)."""
    from numba.core import cgutils
    from numba.np.arrayobj import make_array, populate_array  # building the kernel only

    sizes_of = list(shape) if isinstance(shape, types.BaseTuple) else [shape]
    array_type = types.Array(dtype.dtype, len(sizes_of), "C")

    def codegen(context: Any, builder: Any, signature: Any, args: Any) -> Any:
        values = cgutils.unpack_tuple(builder, args[0]) if isinstance(shape, types.BaseTuple) else [args[0]]
        sizes = [context.cast(builder, v, t, types.intp) for v, t in zip(values, sizes_of, strict=True)]
        item = context.get_data_type(array_type.dtype)
        strides = [context.get_constant(types.intp, context.get_abi_sizeof(item))]
        for size in reversed(sizes[1:]):
            strides.insert(0, builder.mul(strides[0], size))
        meminfo = context.nrt.meminfo_alloc_aligned(builder, builder.mul(strides[0], sizes[0]), 32)
        array = make_array(array_type)(context, builder)
        data = builder.bitcast(context.nrt.meminfo_data(builder, meminfo), item.as_pointer())
        populate_array(array, data=data, shape=sizes, strides=strides, itemsize=strides[-1], meminfo=meminfo)
        return array._getvalue()

    return array_type(shape, dtype), codegen


@inline
def chunks(runs, size):  # pragma: no cover - compiled
    """(the chunks of one run, of all runs): ceil(size / CHUNK) each, at least one."""
    blocks = max(1, (size + CHUNK - 1) // CHUNK)
    return blocks, runs * blocks


@inline
def chunk_of(job, blocks, size):  # pragma: no cover - compiled
    """Chunk `job`'s (run, first particle, end) in its run's particles."""
    run = job // blocks
    start = (job - run * blocks) * CHUNK
    return run, start, min(start + CHUNK, size)
