"""Which runs can train as one population, and what may differ between its members.

Members of one population share the env setting, the network, the algorithm and every counter of the loop;
only the keys of :data:`MEMBER_KEYS` may differ. :func:`population_signature` is what the population launcher
groups jobs by; :func:`check_population` refuses a group forced together that differs elsewhere.
"""

from __future__ import annotations

from collections.abc import Sequence

from omegaconf import DictConfig, OmegaConf

# What each member sets for itself: its seed, its learning rate, its epsilon schedule, its checkpoint to
# resume from. (Thompson sampling has no schedule; the key still may differ, it is simply unused.)
MEMBER_KEYS = ("seed", "lr", "exploration.eps_init", "exploration.eps_end", "exploration.annealing_fraction",
               "resume")


class PopulationError(ValueError):
    """Runs that cannot share one population program; the message names the first differing key."""


def flat_settings(cfg: DictConfig) -> dict[str, object]:
    """The resolved config as ``{"dotted.key": value}`` (lists stay values)."""
    out: dict[str, object] = {}

    def walk(node: object, prefix: str) -> None:
        if isinstance(node, dict):
            for key, value in node.items():
                walk(value, f"{prefix}{key}.")
        else:
            out[prefix[:-1]] = node

    walk(OmegaConf.to_container(cfg, resolve=True), "")
    return out


def shared_settings(cfg: DictConfig) -> dict[str, object]:
    """Every setting of ``cfg`` that all members of its population must share (all but :data:`MEMBER_KEYS`)."""
    return {key: value for key, value in flat_settings(cfg).items() if key not in MEMBER_KEYS}


def population_signature(cfg: DictConfig) -> str:
    """A string equal for exactly the configs that can train together (the launcher's grouping key)."""
    return repr(sorted(shared_settings(cfg).items()))


def first_difference(a: DictConfig, b: DictConfig) -> tuple[str, object, object] | None:
    """The first shared setting (alphabetically) in which ``a`` and ``b`` differ, with both values."""
    sa, sb = shared_settings(a), shared_settings(b)
    for key in sorted(sa.keys() | sb.keys()):
        if sa.get(key) != sb.get(key):
            return key, sa.get(key), sb.get(key)
    return None


def check_population(cfgs: Sequence[DictConfig]) -> None:
    """Raise :class:`PopulationError` naming the key, unless all ``cfgs`` differ only in :data:`MEMBER_KEYS`."""
    if not cfgs:
        raise PopulationError("a population needs at least one member")
    for index, cfg in enumerate(cfgs[1:], start=1):
        difference = first_difference(cfgs[0], cfg)
        if difference is not None:
            key, first, other = difference
            raise PopulationError(f"members 0 and {index} differ in {key} ({first!r} vs {other!r}); a population "
                                  f"may differ only in {', '.join(MEMBER_KEYS)}")
