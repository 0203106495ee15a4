import sys

from simtest.cli import main

sys.exit(main())
