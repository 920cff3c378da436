"""The population launcher: a Hydra ``Launcher`` that runs the jobs of a sweep as populations.

Hydra hands a launcher the whole sweep at once (``launch(job_overrides, initial_job_idx)``). This one

1. prepares every job as Hydra's own launchers do (``run_job``: the job's folder, its ``.hydra/`` configs,
   ``hydra.job.num``), with a task that only records the job's config and folder;
2. groups the jobs whose configs differ only in the keys a member may set for itself
   (:data:`aia.training.members.MEMBER_KEYS`: seed, learning rate, epsilon schedule, resume) and says, for every job
   that must run alone, which key kept it apart;
3. runs each group as one call of the app's population entry (``task``, a dotted path; by default the one
   the app declares: for ``aia-train`` :func:`aia.apps.train.train_jobs`, which trains the group as one
   population, for ``aia-eval`` :func:`aia.apps.evaluate.evaluate_jobs`, which plans all seeds' ARVI
   episodes in one batch), groups in parallel worker processes up to ``n_jobs``, each with its share of the
   cores as its torch thread pool, the largest first (:func:`aia.training.sweeps.population_work`: the
   longest populations do not end up last, alone on one core); a worker that dies fails its own population
   only, a stop signal ends the sweep after the running populations (:mod:`.workers`);
4. says as each population ends how many have ended, after how long, and which jobs it ran (with how many
   of them failed);
5. returns one ``JobReturn`` per job, completed with the job's own result or failed with its own error.

Its settings are ``conf/hydra/launcher/population.yaml`` (``n_jobs``, ``task``, ``split_to_fill``,
``progress_every_s``), found by Hydra in aia's
config path like the other launchers' (an editable install hides this namespace package from Hydra's plugin
scan, so the settings are not registered from here).
"""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Sequence
from pathlib import Path

from hydra.core.hydra_config import HydraConfig
from hydra.core.utils import JobReturn, JobStatus, configure_log, filter_overrides, run_job, setup_globals
from hydra.plugins.launcher import Launcher
from hydra.types import HydraContext, TaskFunction
from omegaconf import DictConfig, OmegaConf, open_dict

from hydra_plugins.aia_population_launcher.display import PopulationDisplay
from hydra_plugins.aia_population_launcher.workers import Outcome, import_entry, run_group, run_in_workers, training

log = logging.getLogger(__name__)


def group_jobs(cfgs: Sequence[DictConfig], out_dirs: Sequence[str | Path], numbers: Sequence[int] | None = None
               ) -> tuple[list[list[int]], list[str]]:
    """The jobs' indices grouped into populations (in order of first appearance), and a line per job that runs
    alone naming the key that kept it from the first group. Jobs that could share a population but continue
    from different points (``resume=auto`` after a sweep grew: some jobs' folders hold checkpoints, others
    none) train as one population per point, with a line per population saying where it starts. ``numbers``
    are the jobs' numbers in those lines (default: their indices)."""
    sweeps = training()
    numbers = list(numbers) if numbers is not None else list(range(len(cfgs)))
    groups: dict[tuple[str, str], list[int]] = {}
    starts: dict[str, dict[str, str]] = {}  # per signature: each resume point's words
    for index, (cfg, out_dir) in enumerate(zip(cfgs, out_dirs, strict=True)):
        signature, point = sweeps.population_signature(cfg), sweeps.resume_point(cfg, Path(out_dir))
        groups.setdefault((signature, repr(point)), []).append(index)
        starts.setdefault(signature, {})[repr(point)] = _start(point)
    notes = [f"{_job_numbers([numbers[i] for i in group])}: {starts[signature][point]} (a population of "
             f"{'its' if len(group) == 1 else 'their'} own)"
             for (signature, point), group in groups.items() if len(starts[signature]) > 1]
    grouped = list(groups.values())
    for group in grouped[1:]:
        difference = sweeps.first_difference(cfgs[group[0]], cfgs[grouped[0][0]]) if len(group) == 1 else None
        if difference is not None:
            key, own, other = difference
            notes.append(f"job {numbers[group[0]]} runs alone: its {key}={own!r} differs from job "
                         f"{numbers[grouped[0][0]]}'s {other!r}")
    return grouped, notes


def _start(point: tuple[int, ...] | str | None) -> str:
    """Where a job with this :func:`~aia.training.sweeps.resume_point` starts, in words."""
    if point is None:
        return "starting fresh"
    if isinstance(point, tuple):
        return f"resuming from frame {point[0]:,}"
    # a checkpoint it cannot read, or a run it may not start over (resume=null): it fails alone, saying why
    return f"cannot start from {point} (it fails alone, saying why)"


def split_to_fill(groups: list[list[int]], processes: int) -> list[list[int]]:
    """``groups`` with the largest split in two (its first half keeps its place) until there are ``processes``
    of them or none has two jobs left: work for every process when a sweep has fewer populations."""
    groups = [list(g) for g in groups]
    while len(groups) < processes and max(len(g) for g in groups) > 1:
        index = max(range(len(groups)), key=lambda i: len(groups[i]))
        group = groups[index]
        half = (len(group) + 1) // 2
        groups[index:index + 1] = [group[:half], group[half:]]
    return groups


def largest_first(groups: list[list[int]], cfgs: Sequence[DictConfig]) -> list[list[int]]:
    """``groups`` by decreasing :func:`~aia.training.sweeps.population_work` (ties keep their order)."""
    population_work = training().population_work
    return sorted(groups, key=lambda group: -population_work([cfgs[i] for i in group]))


def _job_numbers(numbers: list[int]) -> str:
    """``"jobs 20-29"`` for a run of consecutive job numbers, else ``"jobs 3, 7, 9"`` (one job: ``"job 3"``)."""
    if len(numbers) == 1:
        return f"job {numbers[0]}"
    if numbers == list(range(numbers[0], numbers[0] + len(numbers))):
        return f"jobs {numbers[0]}-{numbers[-1]}"
    return "jobs " + ", ".join(map(str, numbers))


def _sizes(groups: list[list[int]], noun: str = "population", nouns: str = "populations") -> str:
    """``"2 populations of 2 and 3 members"``, ``"1 population of 4 members"``, ``"3 populations of 1 member each"``
    (``noun`` and ``nouns`` name one group and several)."""
    sizes = [len(group) for group in groups]
    counted = f"{len(sizes)} {noun if len(sizes) == 1 else nouns}"
    if len(set(sizes)) == 1:
        members = f"{sizes[0]} member" + ("s" if sizes[0] != 1 else "") + (" each" if len(sizes) > 1 else "")
    else:
        members = f"{', '.join(map(str, sizes[:-1]))} and {sizes[-1]} members"
    return f"{counted} of {members}"


def _minutes(seconds: float) -> str:
    """``"12:05"`` (minutes and seconds)."""
    return f"{int(seconds) // 60}:{int(seconds) % 60:02d}"


def done_line(done: int, total: int, start: float, name: str, outcome: Outcome) -> str:
    """``"population launcher: 2/3 done after 1:05: jobs 0-1 (1 of 2 failed)"`` (one job: ``"job 4 (failed)"``):
    what is said as a population ends (``start``: the ``time.monotonic()`` the populations started at)."""
    failed = sum(not ok for ok, _ in outcome)
    if failed:
        name += " (failed)" if len(outcome) == 1 else f" ({failed} of {len(outcome)} failed)"
    return f"population launcher: {done}/{total} done after {_minutes(time.monotonic() - start)}: {name}"


class PopulationLauncher(Launcher):
    """Launches a sweep as populations (see the module docstring)."""

    def __init__(self, n_jobs: int = 2, task: str | None = None, split_to_fill: bool = False,
                 progress_every_s: float = 30.0) -> None:
        self.n_jobs = n_jobs
        self.task = task
        self.split_to_fill = split_to_fill
        self.progress_every_s = progress_every_s
        self.config: DictConfig | None = None
        self.hydra_context: HydraContext | None = None
        self.task_function: TaskFunction | None = None
        self._composed: dict[tuple[str, ...], DictConfig] = {}

    def setup(self, *, hydra_context: HydraContext, task_function: TaskFunction, config: DictConfig) -> None:
        self.config = config
        self.hydra_context = hydra_context
        self.task_function = task_function
        self._composed = _remember_sweep_configs(hydra_context.config_loader, config)

    def launch(self, job_overrides: Sequence[Sequence[str]], initial_job_idx: int) -> Sequence[JobReturn]:
        setup_globals()
        assert self.config is not None and self.hydra_context is not None
        task = self._task()
        self._check_settings(task)
        configure_log(self.config.hydra.hydra_logging, self.config.hydra.verbose)
        Path(str(self.config.hydra.sweep.dir)).mkdir(parents=True, exist_ok=True)
        for i, overrides in enumerate(job_overrides):
            log.info(f"\t#{initial_job_idx + i} : {' '.join(filter_overrides(overrides))}")
        prepared, configs = zip(*(self._prepare(initial_job_idx + i, overrides)
                                  for i, overrides in enumerate(job_overrides)), strict=True)
        # run_job configured each job's logging while preparing its folder: back to the launcher's own
        configure_log(self.config.hydra.hydra_logging, self.config.hydra.verbose)
        groups, notes = group_jobs(configs, [job.return_value for job in prepared],
                                   [job.hydra_cfg.hydra.job.num for job in prepared])
        print(f"population launcher: {len(prepared)} jobs in {_sizes(groups)}")
        for note in notes:
            print(f"population launcher: {note}")
        groups = self._arrange(groups, configs)
        names = [_job_numbers([prepared[i].hydra_cfg.hydra.job.num for i in group]) for group in groups]
        members = [([OmegaConf.to_container(configs[i]) for i in group], [prepared[i].return_value for i in group])
                   for group in groups]
        outcomes = self._run(task, members, names)
        for group, results in zip(groups, outcomes, strict=True):
            for index, (ok, result) in zip(group, results, strict=True):
                prepared[index].status = JobStatus.COMPLETED if ok else JobStatus.FAILED
                prepared[index].return_value = result
                if not ok:
                    log.error(f"job {prepared[index].hydra_cfg.hydra.job.num} failed: {result}")
        return list(prepared)

    def _arrange(self, groups: list[list[int]], configs: Sequence[DictConfig]) -> list[list[int]]:
        """The populations in the order they start: split to fill the processes (``split_to_fill``), and
        the largest first when several run at once."""
        if self.split_to_fill and len(groups) < self.n_jobs:
            groups = split_to_fill(groups, self.n_jobs)
            print(f"population launcher: split into {_sizes(groups, 'process', 'processes')} (split_to_fill)")
        if min(self.n_jobs, len(groups)) > 1:  # the largest first (stable): processes take the groups in this order
            groups = largest_first(groups, configs)
        return groups

    def _run(self, task: str, members: list[tuple[list[dict], list[str]]], names: list[str]) -> list[Outcome]:
        """Run each population (its members' configs and job folders) on this machine, ``n_jobs`` at a time in
        worker processes with a share of the cores each (in this process if one runs at a time), saying as
        each ends; the outcomes in the populations' order. ``names``: each population's job numbers."""
        parallel = max(1, min(self.n_jobs, len(members)))
        threads = max(1, (os.cpu_count() or 1) // parallel) if parallel > 1 else None
        calls = [(task, cfgs, out_dirs, threads) for cfgs, out_dirs in members]
        display = PopulationDisplay(names, parallel, every_s=self.progress_every_s)
        if parallel == 1:
            finished = ((index, run_group(*call)) for index, call in enumerate(calls))
        else:  # as each population ends, whatever its place in the order; one bar per running population
            finished = run_in_workers(calls, parallel, names, display)
        outcomes: list[Outcome] = [[] for _ in calls]
        start = time.monotonic()
        try:
            for done, (index, results) in enumerate(finished, 1):
                outcomes[index] = results
                display.write(done_line(done, len(calls), start, names[index], results))
        finally:
            display.close()
        return outcomes

    def _task(self) -> str:
        """The population entry: ``task`` if set, else the one the app declares (``hydra_app(population=)``)."""
        task = self.task or getattr(self.task_function, "population_task", None)
        if task is None:
            from aia.config.errors import ConfigError  # imported here: see workers.training

            raise ConfigError("hydra.launcher.task", self.task, "the dotted path of a population entry (this app "
                              "declares none: hydra/launcher=population serves aia-train and aia-eval)")
        return task

    def _check_settings(self, task: str) -> None:
        """Refuse a bad ``hydra.launcher.*`` value with a :class:`~aia.config.errors.ConfigError` (the app prints one
        line and exits with status 2) before any job folder is made."""
        from aia.config.checks import check_flag, check_number, require  # imported here: see workers.training

        check_number("hydra.launcher.n_jobs", self.n_jobs, ge=1, integer=True)
        check_flag("hydra.launcher.split_to_fill", self.split_to_fill)
        check_number("hydra.launcher.progress_every_s", self.progress_every_s, ge=0)
        try:
            entry = import_entry(task)
        except (ImportError, AttributeError, ValueError):
            entry = None
        require(callable(entry), "hydra.launcher.task", task, "the dotted path of a population entry such as "
                "aia.apps.train.train_jobs or aia.apps.evaluate.evaluate_jobs")

    def _prepare(self, index: int, overrides: Sequence[str]) -> tuple[JobReturn, DictConfig]:
        """The job's folder and ``.hydra/`` configs by Hydra's ``run_job`` (its return value is the folder),
        and its task config resolved in the job's own Hydra context."""
        assert self.config is not None and self.hydra_context is not None
        sweep_config = self._composed.pop(tuple(overrides), None)
        if sweep_config is None:  # not composed by the sweeper's check (or taken already)
            sweep_config = self.hydra_context.config_loader.load_sweep_config(self.config, list(overrides))
        with open_dict(sweep_config):
            sweep_config.hydra.job.id = f"{sweep_config.hydra.job.name}_{index}"
            sweep_config.hydra.job.num = index
        ret = run_job(hydra_context=self.hydra_context, task_function=_job_folder, config=sweep_config,
                      job_dir_key="hydra.sweep.dir", job_subdir_key="hydra.sweep.subdir")
        if ret.status != JobStatus.COMPLETED:
            raise RuntimeError(f"could not prepare job {index}: {ret._return_value}")
        return ret, OmegaConf.create(OmegaConf.to_container(ret.cfg, resolve=True))


def _remember_sweep_configs(loader, master: DictConfig) -> dict[tuple[str, ...], DictConfig]:
    """The sweep configs ``loader`` composes from now on for the sweep config ``master``, by overrides (filled
    as it goes).

    Hydra's sweepers compose every job's config before launching, to check the batch
    (``Sweeper.validate_batch_is_legal``), and throw it away; the launcher then composed it again. Each
    composition costs about 0.16 s on one core: for scripts/reproduce.sh's 80 learner jobs, 13 s of the 27 s
    spent before the first population started (2026-12-03). Wrapping the loader's ``load_sweep_config`` on
    this instance lets :meth:`PopulationLauncher._prepare` take the sweeper's composition instead (each once:
    ``run_job`` writes into it).
    """
    composed: dict[tuple[str, ...], DictConfig] = {}
    compose = getattr(loader.load_sweep_config, "__wrapped__", loader.load_sweep_config)  # set up once more

    def load_sweep_config(master_config: DictConfig, sweep_overrides: list[str]) -> DictConfig:
        sweep_config = compose(master_config=master_config, sweep_overrides=sweep_overrides)
        if master_config is master:
            composed[tuple(sweep_overrides)] = sweep_config
        return sweep_config

    load_sweep_config.__wrapped__ = compose
    loader.load_sweep_config = load_sweep_config
    return composed


def _job_folder(cfg: DictConfig) -> str:
    """The preparation task: the job's output folder (``run_job`` has created it and saved the configs)."""
    return str(HydraConfig.get().runtime.output_dir)
