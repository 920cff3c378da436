"""Imported only by the fork server of a population launcher's workers (multiprocessing's ``forkserver`` preload,
``hydra_plugins/aia_population_launcher/workers.py``, after ``aia.training.sweeps``): marks the process as a fork
server, which only imports and forks, so that its children keep torch's OpenMP team
(:func:`aia.runtime.cpu_threads.serve_forks`), and ends it quickly (:func:`aia.runtime.process_exit.freeze_at_exit`:
the server outlives the launcher by its teardown, holding the launcher's output open meanwhile)."""

from aia.runtime.cpu_threads import serve_forks
from aia.runtime.process_exit import freeze_at_exit

serve_forks()
freeze_at_exit()
