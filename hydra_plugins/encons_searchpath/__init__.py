"""Adds encons' ``sweeps/`` folder to Hydra's search path so ``sweeps=NAME`` selects a sweep."""

from hydra.core.config_search_path import ConfigSearchPath
from hydra.plugins.search_path_plugin import SearchPathPlugin


class EnconsSearchPathPlugin(SearchPathPlugin):
    def manipulate_search_path(self, search_path: ConfigSearchPath) -> None:
        from encons.paths import sweeps_root

        search_path.append(provider="encons", path=f"file://{sweeps_root()}")
