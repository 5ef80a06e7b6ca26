import sys

from services.vision.node import main

sys.exit(main())
