import sys

from acl3d.cli import main

sys.exit(main())
