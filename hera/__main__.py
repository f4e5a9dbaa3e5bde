"""``python -m hera`` runs the command line."""

import sys

from hera.cli import main

sys.exit(main())
