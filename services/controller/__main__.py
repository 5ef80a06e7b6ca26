import sys

from services.controller.node import main

sys.exit(main())
