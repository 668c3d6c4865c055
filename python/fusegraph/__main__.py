"""`python -m fusegraph ...`: the fusegraph command line, with Python ops.

The same commands as the `fusegraph` binary (`run`, `sweep`, `validate`,
`nodes`, ...), and `--python FILE` / `[graph] python = [...]` load ops
declared with `@fusegraph.op` from Python files.
"""

import sys


def main() -> int:
    from fusegraph import _native

    return _native.cli(["fusegraph", *sys.argv[1:]])


if __name__ == "__main__":
    sys.exit(main())
