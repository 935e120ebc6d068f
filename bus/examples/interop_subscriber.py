"""Subscribes to a qfleet run from Python with iceoryx2's own bindings (PyPI `iceoryx2` 0.10).

    pip install iceoryx2==0.10.0
    cargo run -p bus --example interop_publisher -- demo 5 &
    python3 bus/examples/interop_subscriber.py demo

The ctypes classes are taken from bus-schema/README.md, whose layout section is generated from
the Rust types and checked by a test, so this script cannot drift from the wire contract.
"""

import ctypes  # noqa: F401  (used by the README classes)
import pathlib
import sys
import time

import iceoryx2 as iox2

README = pathlib.Path(__file__).resolve().parents[2] / "bus-schema" / "README.md"
MIRROR = README.read_text().split("### Python `ctypes` mirror", 1)[1]
exec(MIRROR.split("```python\n", 1)[1].split("```", 1)[0])  # noqa: S102

run_id = sys.argv[1]
config = iox2.config.default()
config.global_cfg.prefix = iox2.FileName.new(f"qfleet.{run_id}.")
node = iox2.NodeBuilder.new().config(config).create(iox2.ServiceType.Ipc)


def subscribe(topic, payload):
    service = (
        node.service_builder(iox2.ServiceName.new(f"qfleet/{run_id}/{topic}"))
        .publish_subscribe(payload)
        .open()
    )
    return service.subscriber_builder().create()


state = subscribe("robot/state", RobotState)  # noqa: F821
merged = subscribe("coord/merged", MergedHintBatch)  # noqa: F821
seen_state = seen_merged = 0
deadline = time.monotonic() + 10
while time.monotonic() < deadline and (seen_state < 3 or seen_merged < 3):
    while (sample := state.receive()) is not None:
        s = sample.payload().contents
        seen_state += 1
        print(f"state robot {s.robot_id} episode {s.episode} cell ({s.cell_x},{s.cell_y}) "
              f"status {s.status} seq {s.seq}")
    while (sample := merged.receive()) is not None:
        m = sample.payload().contents
        seen_merged += 1
        hints = [(m.entries[i].cell, m.entries[i].action, m.entries[i].q) for i in range(m.count)]
        print(f"merged seq {m.coordinator_seq} hints {hints}")
    time.sleep(0.05)
sys.exit(0 if seen_state >= 3 and seen_merged >= 3 else 1)
