"""Prints what a rerun recording (.rrd) holds, read with rerun's own SDK, as JSON.

For each entity path: the rows logged to it, the `frame` timeline's values, and per component
column the number of instances in each row. Used by tests/rerun_cli.rs.
"""

import json
import sys

import rerun.experimental as rrx


def contents(path):
    reader = rrx.RrdReader(path)
    recordings = reader.recordings()
    entities = {}
    for chunk in reader.stream():
        entity = entities.setdefault(
            chunk.entity_path, {"rows": 0, "frames": [], "instances": {}}
        )
        entity["rows"] += chunk.num_rows
        batch = chunk.to_record_batch()
        for name in batch.schema.names:
            if name == "frame":
                entity["frames"].extend(int(f) for f in batch.column(name).to_pylist())
            elif ":" in name:
                counts = entity["instances"].setdefault(name, [])
                column = batch.column(name).to_pylist()
                counts.extend(len(v) if v is not None else 0 for v in column)
    for entity in entities.values():
        entity["frames"].sort()
    return {
        "application_id": recordings[0].application_id,
        "recordings": len(recordings),
        "entities": entities,
    }


if __name__ == "__main__":
    print(json.dumps(contents(sys.argv[1])))
