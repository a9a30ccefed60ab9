import sys

from cnep.pipeline.cli.main import main

sys.exit(main())
