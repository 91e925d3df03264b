"""How freed memory goes back to the operating system: glibc's malloc, tuned for training loops.

A training step allocates and frees the same large buffers every time: oneDNN's LSTM workspace,
activations kept for backward, their gradients (a few MB each). glibc's defaults give that memory
back to the kernel after each step: its *dynamic* mmap threshold maps buffers above it afresh, and
the top of the heap is trimmed whenever more than ``M_TRIM_THRESHOLD`` lies free. The next step then
takes a page fault, and the kernel zeroes a new page, for every 4 kB it touches again.

Measured here (2-core Zen 5, one thread, nothing else running; ``bench/allocator.py``, medians of 3):

* LSTM-3LR on ``bandai2_locomotion``: 67.5 ms per optimiser step and 7,797 minor page faults with
  glibc's defaults; 54.2 ms and 628 with the settings below (1.25x; the faults include start-up);
* SA-GCN on ``h36m``: 187.4 ms and 16,999 faults; 167.9 ms and 3,919 (1.12x);
* ERD, acLSTM, GloGen, c-SkeletonGAN, one training round each: within 2 % either way (they fault
  little or compute much).

Two stages at a time (``make run``), where both processes' faults compete for the kernel and memory,
the gain is larger: ERD and LSTM-3LR stages took 24-33 % less wall time (LSTM-3LR on ``cmu_aclstm``
8 %), training as a whole 15 % less (9,678 → 8,216 s), at the same bits.

The losses are bit for bit the same: where memory comes from does not change arithmetic.

:func:`tune` (called by the pipelines' entry points, ``pipelines/_common.py``) sets, through
``mallopt``:

* ``M_MMAP_THRESHOLD`` = :data:`MMAP_THRESHOLD` (32 MiB, glibc's largest on 64-bit): buffers below
  it come from the heap and are reused, and the threshold stops moving;
* ``M_TRIM_THRESHOLD`` = :data:`TRIM_THRESHOLD` (1 GiB): free memory at the top of the heap is kept
  for the next step rather than returned at once. A process's resident size stays at its peak; it
  is given back when the process ends (a stage is one process).

Set ``MALLOC_MMAP_THRESHOLD_`` or ``MALLOC_TRIM_THRESHOLD_`` (glibc's own variables) to choose
otherwise, or ``MOTIONSYNTH_MALLOC=glibc`` to keep glibc's defaults (what ``bench/allocator.py``
compares against): then :func:`tune` changes nothing. Other C libraries (macOS, musl): nothing to do.
"""

from __future__ import annotations

import ctypes
import os

#: buffers below this many bytes are taken from (and kept in) the heap; glibc's maximum on 64-bit
MMAP_THRESHOLD = 32 * 1024 * 1024
#: free bytes at the top of the heap kept before glibc returns them to the kernel
TRIM_THRESHOLD = 1024 * 1024 * 1024
#: glibc's own variables: either set means the user has chosen, and :func:`tune` leaves malloc alone
GLIBC_ENV = ("MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_")
#: ``glibc``: keep glibc's defaults (the comparison of ``bench/allocator.py``)
OPT_OUT_ENV = "MOTIONSYNTH_MALLOC"
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3   # mallopt parameter numbers (<malloc.h>)


def tune() -> bool:
    """Apply the thresholds above to this process's glibc malloc. Returns whether it did: ``False``
    where the environment sets one of :data:`GLIBC_ENV` or ``MOTIONSYNTH_MALLOC=glibc``, or the C
    library is not glibc."""
    if any(k in os.environ for k in GLIBC_ENV) or os.environ.get(OPT_OUT_ENV) == "glibc":
        return False
    try:
        mallopt = ctypes.CDLL(None).mallopt   # the C library the process runs on (no ldconfig search)
    except (OSError, AttributeError):         # not glibc: macOS has no mallopt
        return False
    mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    return bool(mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD)) and bool(mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD))
