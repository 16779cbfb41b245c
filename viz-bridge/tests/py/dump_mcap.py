#!/usr/bin/env python3
"""Reads a session MCAP with the reference MCAP reader (PyPI `mcap` + `mcap-ros2-support`) and
writes, for every session topic, its schema name and each message described by
ros_normal.describe: the recorded counterpart of ros_peer.py's live capture.

    dump_mcap.py FILE.mcap --out OUT.json [--namespace /arthrosim]
"""
import argparse
import json
import sys

from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from ros_normal import TOPICS, describe, full_name


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("mcap")
    ap.add_argument("--out", required=True)
    ap.add_argument("--namespace", default="/arthrosim")
    args = ap.parse_args()
    by_name = {full_name(args.namespace, rel): key for key, rel in TOPICS.items()}
    types, messages = {}, {key: [] for key in TOPICS}
    with open(args.mcap, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        for channel in summary.channels.values():
            key = by_name.get(channel.topic)
            if key is not None:
                types[key] = summary.schemas[channel.schema_id].name
        for _schema, channel, _message, decoded in reader.iter_decoded_messages(
            topics=list(by_name)
        ):
            key = by_name[channel.topic]
            messages[key].append(describe(key, decoded))
    with open(args.out, "w") as f:
        json.dump({"types": types, "messages": messages}, f)
    print(json.dumps({k: len(v) for k, v in messages.items()}), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
