import sys

from services.sim.node import main

sys.exit(main())
