import sys

from armexp.cli import main

sys.exit(main())
