"""`python -m edgepick` (and `torchrun -m edgepick train ...`) run the CLI."""

from edgepick.cli import main

if __name__ == "__main__":
    main()
