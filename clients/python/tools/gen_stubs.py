"""Regenerates adp_client/_proto/adp_pb2.py from the project's proto (proto/proto/adp/v1/adp.proto).

The client stubs need no generated module: adp_client/_proto/stubs.py makes them from the
descriptors in adp_pb2.

Usage: python tools/gen_stubs.py [--check]

The generated module is committed so that `pip install ./clients/python` needs no protoc;
`--check` (run by the test suite) fails when it differs from what the proto generates now.
"""

import pathlib
import sys
import tempfile

HERE = pathlib.Path(__file__).resolve().parent
PROTO = HERE.parent.parent.parent / "proto" / "proto" / "adp" / "v1" / "adp.proto"
OUT = HERE.parent / "src" / "adp_client" / "_proto"


def generate() -> dict:
    """Returns {file name: text} of the module the proto generates now."""
    from grpc_tools import protoc
    import grpc_tools

    include = pathlib.Path(grpc_tools.__file__).parent / "_proto"
    with tempfile.TemporaryDirectory() as tmp:
        rc = protoc.main(
            [
                "protoc",
                f"-I{PROTO.parent}",
                f"-I{include}",
                f"--python_out={tmp}",
                str(PROTO),
            ]
        )
        if rc != 0:
            raise SystemExit(f"protoc failed on {PROTO} (exit {rc})")
        return {"adp_pb2.py": (pathlib.Path(tmp) / "adp_pb2.py").read_text()}


def main() -> int:
    files = generate()
    if "--check" in sys.argv[1:]:
        stale = [n for n, t in files.items() if not (OUT / n).is_file() or (OUT / n).read_text() != t]
        if stale:
            print(f"stale generated stubs {stale}: run python {pathlib.Path(__file__).name}", file=sys.stderr)
            return 1
        return 0
    for name, text in files.items():
        (OUT / name).write_text(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
