"""sweepcast's engines: pure functions on numpy arrays, run by the service's Ray workers.

numba runs our parallel kernels on GNU OpenMP threads, which by default spin for a while after each
kernel, waiting for the next. In a service that is wasted CPU: the live path and concurrent viewers
launch many short kernels from several threads of one process while other processes share the cores,
and the spinning threads took the CPU from the working ones (2 cores under load: packing a live
frame set 6.7 ms CPU spinning against 1.1 ms sleeping). So the threads sleep between kernels unless
the operator chose otherwise. libgomp reads this when it loads, at numba's first parallel kernel:
setting it here, on the package's import, comes first in every process that runs our kernels.

For the same reason the package tells numba, before any kernel module is decorated, to file cached kernels
where any install of the same sources finds them (:mod:`workers.portable_cache`).
"""
import os

from workers.portable_cache import register as _register_portable_cache

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
_register_portable_cache()
