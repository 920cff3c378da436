"""What the fork server of a population launcher's workers imports before it forks them (multiprocessing's
``forkserver`` preload, :func:`.workers.run_in_workers`).

A spawned worker imported torch, TensorDict and TorchRL itself: 4.5 s of CPU a worker on the 2-core CPU before
its population started. The fork server is a fresh interpreter that imports them once and then only forks, so
each worker starts with them imported. It runs no parallel region, so its children keep torch's OpenMP team
(:func:`aia.runtime.cpu_threads.serve_forks`)."""

import aia.training.sweeps  # noqa: F401  (the workers' entry into training: torch, TensorDict, TorchRL)
from aia.runtime import cpu_threads
from aia.runtime.process_exit import freeze_at_exit

cpu_threads.serve_forks()
freeze_at_exit()  # the server ends after the launcher; a quick end frees the launcher's output pipe sooner
