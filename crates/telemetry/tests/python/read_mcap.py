"""Reads a TEP dataset with the official MCAP Python reader and prints a JSON summary.

Usage: read_mcap.py FILE.mcap

Only the schema embedded in the file is used to decode the messages (mcap-protobuf-support builds
the message classes from its FileDescriptorSet); nothing of terl is imported. The terl-telemetry
test compares the summary with what it wrote.
"""

import json
import sys

from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory


def main(path: str) -> None:
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        count = 0
        priority_sum = 0.0
        first = None
        schema_info = None
        for schema, channel, _message, sample in reader.iter_decoded_messages(
            topics=["/tep/samples"], log_time_order=False
        ):
            if first is None:
                schema_info = {
                    "schema_name": schema.name,
                    "schema_encoding": schema.encoding,
                    "message_encoding": channel.message_encoding,
                    "message_type": sample.DESCRIPTOR.full_name,
                }
                first = {
                    "task": sample.task,
                    "trajectory_id": sample.trajectory_id,
                    "step": sample.step,
                    "priority": sample.priority,
                    "obs_len": len(sample.obs),
                    "next_obs_len": len(sample.next_obs),
                    "goal_obs_len": len(sample.goal_obs),
                    "action": list(sample.action),
                }
            count += 1
            priority_sum += sample.priority
    print(
        json.dumps(
            {
                "count": count,
                "statistics_message_count": (
                    summary.statistics.message_count
                    if summary is not None and summary.statistics is not None
                    else None
                ),
                "priority_sum": priority_sum,
                "first": first,
                **(schema_info or {}),
            }
        )
    )


if __name__ == "__main__":
    main(sys.argv[1])
