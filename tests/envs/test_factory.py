"""make_env and the env config: every bad input is a one-line ConfigError naming the key and the value."""

from __future__ import annotations

import pytest

from aia.config.errors import ConfigError
from aia.envs import make_env
from aia.envs.config import TrackingConfig
from aia.envs.factory import available_settings, load_env_config, to_tracking_config

CASES = [
    ("nowhere", [], "env='nowhere'", "empty1"),
    ("empty1", ["map=atlantis"], "env.map='atlantis'", "obstacles4"),
    ("empty1", ["num_targets=0"], "env.num_targets=0", ">= 1"),
    ("empty1", ["dt=-0.5"], "env.dt=-0.5", "> 0"),
    ("empty1", ["sensor.fov_deg=400"], "env.sensor.fov_deg=400", "<= 360"),
    ("empty1", ["belief.det_cap=0"], "env.belief.det_cap=0", "or null"),
    ("empty1", ["target.init_distance=[5,1]"], "env.target.init_distance=[5.0, 1.0]", "min <= max"),
    ("empty1", ["robot.linear_speeds=[]"], "env.robot.linear_speeds=[]", "non-empty"),
    ("empty1", ["belief.init_offset_shape=ring"], "env.belief.init_offset_shape='ring'", "disk"),
    ("empty1", ["sensr.range=3"], "env.sensr.range='3'", "one of env's keys (did you mean env.sensor?)"),
    ("empty1", ["env.sensor.rang=3"], "env.sensor.rang='3'", "(did you mean env.sensor.range?): range, fov_deg"),
    ("empty1", ["sensor.range=far"], "env.sensor.range='far'", "expected a number"),
    ("empty1", ["belief=3"], "env.belief=3", "keys under env.belief (env.belief.<key>=<value>), not a value"),
    ("empty1", ["map=/nonexistent/room.yaml"], "env.map='/nonexistent/room.yaml'", "does not exist"),
    ("empty1", ["belief.filter=pf2"], "env.belief.filter='pf2'", "'kf', 'ukf'"),
    ("empty1", ["target.model=teleport"], "env.target.model='teleport'", "'se2_sine'"),
    ("empty1", ["belief.model=bicycle"], "env.belief.model='bicycle'", "'se2_velocity'"),
    ("ttenv_v2", ["belief.filter=kf"], "env.belief.filter='kf'", "ukf or particle with belief.model=se2"),
    ("empty1", ["belief.ukf_kappa=0"], "env.belief.ukf_kappa=0", "> 0"),
]


@pytest.mark.parametrize("setting, overrides, named, allowed", CASES, ids=[c[2] for c in CASES])
def test_bad_env_input_is_one_line_naming_key_and_value(setting, overrides, named, allowed):
    with pytest.raises(ConfigError) as info:
        make_env(setting, overrides=overrides)
    message = str(info.value)
    assert named in message and allowed in message and "\n" not in message


def test_a_bad_type_in_a_config_node_is_named():
    # worded as the apps word the same value on a command line
    for node, message in (({"sensor": {"range": "far"}}, "env.sensor.range='far': expected a number"),
                          ({"sensor": {"rang": 3}}, "env.sensor.rang=3: expected one of env.sensor's keys (did you "
                                                    "mean env.sensor.range?): range,"),
                          ({"belief": 3}, "env.belief=3: expected keys under env.belief"),
                          ({"random_map": {"size": "x"}}, "env.random_map.size='x': expected a list")):
        with pytest.raises(ConfigError) as info:
            to_tracking_config(node)
        assert str(info.value).startswith(message), info.value
    with pytest.raises(ConfigError, match="num_targets=1.5"):
        TrackingConfig(num_targets=1.5)


def test_overrides_may_be_written_as_the_apps_write_them():
    assert load_env_config("empty1", ["env.belief.det_cap=null", "sensor.range=12"]) == load_env_config(
        "empty1", ["belief.det_cap=null", "env.sensor.range=12"])
    assert load_env_config("empty1", ["env.belief.det_cap=null"]).belief.det_cap is None


def test_internal_configs_are_not_settings():
    assert "variant_2019" not in available_settings() and "schema" not in available_settings()
    assert {"empty1", "obstacles1", "small2", "small3", "small3_2019"} <= set(available_settings())
    assert make_env("small3_2019").base_env.config.features.relative_velocity == "2019"  # the variant applies
