import sys

from services.actuation.node import main

sys.exit(main())
