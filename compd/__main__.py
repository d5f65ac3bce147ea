import sys

from compd.cli import main

sys.exit(main())
