#!/usr/bin/env python3
"""Check an `adp export` directory with onnxruntime and numpy.

Usage: check_onnx.py DIR

DIR holds policy.onnx, policy.safetensors and policy.json (written by `adp export`) and
reference.json ({"tolerance", "obs": [[...]], "action": [[...]]}: observations and the actions
burn computed for them; `cargo test` writes one to target/tmp/export-check). Checks that

- onnxruntime loads policy.onnx, whose input and output are named and shaped as policy.json
  says, with a symbolic batch dimension;
- its actions match the reference within the tolerance, for the whole batch and for one row;
- a numpy forward pass through policy.safetensors, in the layout policy.json documents,
  matches the reference too.

Exits 0 when everything holds, 1 with a message otherwise.
"""

import json
import struct
import sys

import numpy as np
import onnxruntime as ort

import check_main


def read_safetensors(path):
    """The tensors of a safetensors file as a dict of float32 arrays."""
    data = path.read_bytes()
    (header_len,) = struct.unpack("<Q", data[:8])
    header = json.loads(data[8 : 8 + header_len])
    header.pop("__metadata__", None)
    body = data[8 + header_len :]
    tensors = {}
    for name, info in header.items():
        if info["dtype"] != "F32":
            raise ValueError(f"{path}: tensor {name} has dtype {info['dtype']}, expected F32")
        start, end = info["data_offsets"]
        tensors[name] = np.frombuffer(body[start:end], dtype="<f4").reshape(info["shape"])
    return tensors


def safetensors_forward(tensors, obs):
    """relu(x W^T + b) through the hidden layers, tanh on the last one."""
    count = len(tensors) // 2
    x = obs
    for i in range(count):
        x = x @ tensors[f"layers.{i}.weight"].T + tensors[f"layers.{i}.bias"]
        x = np.maximum(x, 0.0) if i < count - 1 else np.tanh(x)
    return x


def check(directory):
    """A list of failure messages (empty when the export is good)."""
    card = json.loads((directory / "policy.json").read_text())
    reference = json.loads((directory / "reference.json").read_text())
    tolerance = float(reference["tolerance"])
    obs = np.asarray(reference["obs"], dtype=np.float32)
    want = np.asarray(reference["action"], dtype=np.float32)
    network = card["network"]
    obs_dim, act_dim = card["observation"]["dim"], card["action"]["dim"]
    failures = []
    if obs.shape[1] != obs_dim or want.shape[1] != act_dim:
        failures.append(f"reference shapes {obs.shape}, {want.shape} do not fit {obs_dim} -> {act_dim}")

    onnx_path = directory / network["onnx_file"]
    session = ort.InferenceSession(str(onnx_path), providers=["CPUExecutionProvider"])
    (inp,), (out,) = session.get_inputs(), session.get_outputs()
    if inp.name != network["onnx_input"] or out.name != network["onnx_output"]:
        failures.append(f"{onnx_path}: input/output named {inp.name}/{out.name}")
    if isinstance(inp.shape[0], int) or inp.shape[1] != obs_dim or out.shape[1] != act_dim:
        failures.append(f"{onnx_path}: shapes {inp.shape} -> {out.shape}, expected [batch, {obs_dim}] -> [batch, {act_dim}]")

    results = {
        "onnxruntime, batch": session.run([out.name], {inp.name: obs})[0],
        "onnxruntime, one row": session.run([out.name], {inp.name: obs[:1]})[0],
        "numpy on safetensors": safetensors_forward(
            read_safetensors(directory / network["safetensors_file"]), obs
        ),
    }
    for what, got in results.items():
        expected = want[: len(got)]
        if got.shape != expected.shape:
            failures.append(f"{what}: shape {got.shape}, expected {expected.shape}")
            continue
        diff = float(np.max(np.abs(got - expected)))
        print(f"{what}: {len(got)} observations, max |diff| vs burn {diff:.2e} (tolerance {tolerance:.0e})")
        if not diff <= tolerance:
            failures.append(f"{what}: max |diff| {diff:.3e} exceeds {tolerance:.0e}")
    return failures


def main(argv):
    return check_main.run("check_onnx", __doc__, check, argv, lambda: f" (onnxruntime {ort.__version__})")


if __name__ == "__main__":
    sys.exit(main(sys.argv))
