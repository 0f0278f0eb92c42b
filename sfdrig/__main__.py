import sys

from sfdrig.cli import main

sys.exit(main())
