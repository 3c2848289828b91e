"""``dynenv-pretrain``: the localization/reconstruction pretraining of the agent's encoder (``cli`` says what it does
and why): its data (``data``), what it runs (``model``), its figures (``evaluate``, ``reconstruction_metrics``) and
its training (``train``)."""
from __future__ import annotations

from typing import Sequence


def main(argv: Sequence[str] | None = None) -> int:
    """``cli.main``, here because the installed ``dynenv-pretrain`` script imports ``dynenv_ros.learning.pretrain:main``
    (cheap to import: the command's modules load when it runs)."""
    from dynenv_ros.learning.pretrain.cli import main as cli_main
    return cli_main(argv)
