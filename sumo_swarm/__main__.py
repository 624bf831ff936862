"""``python -m sumo_swarm`` is the ``sumo-swarm`` command."""

import sys

from sumo_swarm.cli import main

sys.exit(main())
