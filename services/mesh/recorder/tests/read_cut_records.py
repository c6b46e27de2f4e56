"""Reads every MCAP file given with the MCAP project's Python reader, as a user's script would
(`make_reader(open(f, "rb")).iter_messages()`), and says how many messages each gave, or why it
could not be read; a `.json` file is parsed with Python's `json` module.

    read_cut_records.py OUT.json FILE.mcap|FILE.json...

OUT.json: {file: {"messages": N, "sequences": [channel sequence numbers], "summary": bool} or
{"error": "..."}}
"""

import json
import sys

from mcap.reader import make_reader


def read(path):
    if path.endswith(".json"):
        with open(path) as f:
            return {"json": type(json.load(f)).__name__}
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        sequences = [message.sequence for _, _, message in reader.iter_messages(log_time_order=False)]
        return {
            "messages": len(sequences),
            "sequences": sequences,
            "summary": summary is not None and len(summary.chunk_indexes) > 0,
        }


def main(out, paths):
    result = {}
    for path in paths:
        try:
            result[path] = read(path)
        except Exception as e:  # noqa: BLE001: any failure is the finding
            result[path] = {"error": f"{type(e).__name__}: {e}"}
    with open(out, "w") as f:
        json.dump(result, f)


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2:])
