import sys

try:
    from .cli import main
except KeyboardInterrupt:
    print("interrupted (Ctrl+C)", file=sys.stderr)
    sys.exit(130)

sys.exit(main())
