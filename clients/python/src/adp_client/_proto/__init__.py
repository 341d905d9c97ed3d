"""Generated protobuf and gRPC modules of adp.v1 (tools/gen_stubs.py)."""
