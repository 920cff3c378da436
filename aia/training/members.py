"""Which runs can train as one population, and what may differ between its members.

Members of one population share the env setting, the network, the loss's family and every counter of the loop;
only the keys of :data:`MEMBER_KEYS` may differ (the fields of :class:`~aia.config.schemas.TrainConfig` declared
``member``), and ``algo.name`` only within one of :data:`FAMILIES`' families (DQN and Double DQN differ only in
their targets' next action; ADFQ has another network and loss).
:func:`population_signature` is what the population launcher groups jobs by; :func:`check_population` refuses
a group forced together that differs elsewhere.
"""

from __future__ import annotations

from collections.abc import Sequence

from omegaconf import DictConfig, OmegaConf

from aia.config.schemas import TrainConfig, keys_where

# What each member sets for itself: its seed, its learning rate, its method (algorithm within a family, and
# exploration: epsilon-greedy with its schedule, or Thompson sampling), its checkpoint to resume from.
MEMBER_KEYS = keys_where(TrainConfig, "member")
# Member keys whose values fall into families: members may differ in such a key only within one family (a value
# not listed is a family of its own).
FAMILIES: dict[str, dict[object, str]] = {"algo.name": {"dqn": "dqn", "ddqn": "dqn"}}
# An ADFQ member-frame's cost relative to a DQN one's, for population_work's order.
ADFQ_WORK = 1.2


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
    """Every setting of ``cfg`` that all members of its population must share: all but :data:`MEMBER_KEYS`, and
    the family of each key of :data:`FAMILIES`."""
    flat = flat_settings(cfg)
    shared = {key: value for key, value in flat.items() if key not in MEMBER_KEYS}
    for key, families in FAMILIES.items():
        if key in flat:
            shared[key] = families.get(flat[key], flat[key])
    return shared


def population_signature(cfg: DictConfig) -> str:
    """A string equal for exactly the configs that can train together (the launcher's grouping key)."""
    return repr(sorted(shared_settings(cfg).items()))


def first_difference(a: DictConfig, b: DictConfig) -> tuple[str, object, object] | None:
    """The first shared setting (alphabetically) in which ``a`` and ``b`` differ, with both values (of a key of
    :data:`FAMILIES`: the members' own values, not their families)."""
    sa, sb = shared_settings(a), shared_settings(b)
    for key in sorted(sa.keys() | sb.keys()):
        if sa.get(key) != sb.get(key):
            if key in FAMILIES:
                return key, OmegaConf.select(a, key), OmegaConf.select(b, key)
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
                                  f"may differ only in {', '.join(MEMBER_KEYS)} ({_families_note()})")


def _families_note() -> str:
    """``FAMILIES`` in words: "algo.name only between dqn and ddqn"."""
    notes = []
    for key, families in FAMILIES.items():
        for family in dict.fromkeys(families.values()):
            members = [value for value, f in families.items() if f == family]
            notes.append(f"{key} only between {', '.join(map(str, members[:-1]))} and {members[-1]}")
    return "; ".join(notes)


def population_work(cfgs: Sequence[DictConfig]) -> float:
    """A rough relative cost of running ``cfgs`` as one population, to start the largest first: members x frames
    (an evaluation: episodes) x (1 + the hidden layers' total width / 256), x 1.2 for ADFQ. Fitted to the
    protocol's populations of 10 on the 2-core CPU (bfloat16 inner layers): per member-frame a 3 x 256
    population took 1.6-1.7x a 3 x 128 one, an ADFQ population 1.14-1.20x a DQN + Double DQN one."""
    first = cfgs[0]
    length = first.get("frames") or first.get("episodes") or 1
    width = sum(first.get("hidden") or ())
    algo_factor = ADFQ_WORK if OmegaConf.select(first, "algo.name") == "adfq" else 1.0
    return len(cfgs) * float(length) * (1.0 + width / 256) * algo_factor
