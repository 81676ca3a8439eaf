import sys

from planar_vo.cli import main

sys.exit(main())
