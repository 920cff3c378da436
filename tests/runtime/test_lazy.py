"""lazy_names: a package's names imported when first asked for, other names refused as a module refuses them."""

from __future__ import annotations

import subprocess
import sys

import pytest

from aia.runtime.lazy import lazy_names


def test_a_name_is_imported_when_asked_for_and_another_is_an_attribute_error():
    getattr_ = lazy_names("pkg", {"dumps": "json"})
    import json

    assert getattr_("dumps") is json.dumps
    with pytest.raises(AttributeError, match="^module 'pkg' has no attribute 'loads'$"):
        getattr_("loads")


def test_the_packages_load_their_torch_modules_only_when_asked():
    code = ("import sys, aia.envs, aia.planners, aia.logging, aia.training.checkpoint_names\n"
            "import aia.evaluation.standalone, aia.evaluation.checkpoints\n"
            "assert 'torch' not in sys.modules\n"
            "from aia.planners import ARVIPolicy\nprint(ARVIPolicy.__module__, 'torch' in sys.modules)")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert result.stdout.split() == ["aia.planners.policy", "True"], result.stderr[-2000:]
