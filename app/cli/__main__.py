"""python -m app.cli: the gsa command."""

import sys

from app.cli import main

sys.exit(main())
