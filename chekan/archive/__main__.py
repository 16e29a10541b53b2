import sys

from chekan.archive.cli import main

if __name__ == "__main__":
    sys.exit(main())
