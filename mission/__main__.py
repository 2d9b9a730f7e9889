import sys

from mission.cli import main

sys.exit(main())
