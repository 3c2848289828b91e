"""``python -m dynenv_ros.learning.pretrain``: ``dynenv-pretrain``."""
import sys

from dynenv_ros.learning.pretrain.cli import main

sys.exit(main())
