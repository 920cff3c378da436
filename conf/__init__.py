"""Hydra configs of aia, installed as the package ``aia.conf``.

Loading this package registers the typed env schema (``env/schema``) that every ``conf/env`` preset
extends, so ``pkg://aia.conf`` composes wherever it is used.
"""

import aia.envs.config  # noqa: F401
