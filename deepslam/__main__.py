"""`python -m deepslam`: the same as the `deepslam` command."""

import sys

from deepslam.cli import main

sys.exit(main())
