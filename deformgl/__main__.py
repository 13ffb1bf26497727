import sys

from deformgl.cli import main

sys.exit(main())
