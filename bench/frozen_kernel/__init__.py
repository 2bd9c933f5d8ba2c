"""The yardstick of ``bench/bench_kernel.py``: a frozen copy of the simulator kernel.

``kernel.py`` and ``nf.py`` here are verbatim copies of ``atc_nf_env/kernel.py`` and
``atc_nf_env/nf.py`` at commit fe97e17 (before the kernel's performance work), with only
their imports pointed at this package. ``advance`` keeps its entry checks: they are part
of what a caller pays per call. numba caches the compiled copy next to these files, apart
from the package's cache.

Not part of the package and never edited: the benchmark measures the current kernel
against it side by side, in one run, so that a speed-up is a ratio on one machine under
one load. The parameter vector of ``atc_nf_env.config.SimConfig.to_params`` is passed
truncated to this copy's ``nf.N_PARAMS`` (parameters added later are appended).
"""
