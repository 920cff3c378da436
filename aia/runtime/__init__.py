"""How aia runs on the machine: ``compiling`` (torch.compile with raised recompile limits, the optimiser step's
private compiled copies), ``memory`` (keep_freed_memory: glibc keeps freed blocks), ``timing`` (PhaseTimer: seconds
per phase of a loop; the machine's matmul rate, ``python -m aia.runtime.timing``), ``cpu_threads`` (run_kernel:
numba kernels on torch's OpenMP team), ``stopping`` (stop signals: StopOnSignals, interrupting), ``process_exit``
(freeze_at_exit: a quick end for entry points' processes), ``lazy`` (lazy_names: a package's names imported on first
use)."""
