"""Check a campaign log's Foxglove channels against Foxglove's own JSON schemas (not a speed
benchmark: a check that needs Node and npm packages, so it lives outside the test suite).

    (cd /tmp/fx && npm install @foxglove/schemas ajv)
    python bench/check_foxglove.py logs/<run>/replay.mcap --node-modules /tmp/fx/node_modules

Every /slider_crank/tf message is validated as foxglove.FrameTransforms and every
/slider_crank/scene message as foxglove.SceneUpdate, with every field the schemas list required
and no field they do not list allowed. Exit code 1 if any message fails.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

from mcap.reader import make_reader

CHECK = """
const Ajv = require("ajv");
const schemas = require("@foxglove/schemas/jsonschema");
const msgs = require(process.argv[2]);
function strict(schema) {
  if (schema && typeof schema === "object") {
    if (schema.type === "object" && schema.properties) schema.additionalProperties = false;
    for (const v of Object.values(schema)) strict(v);
  }
  return schema;
}
const ajv = new Ajv({ strict: false, allErrors: true });
let bad = 0;
for (const [topic, name] of [["/slider_crank/tf", "FrameTransforms"],
                             ["/slider_crank/scene", "SceneUpdate"]]) {
  const validate = ajv.compile(strict(JSON.parse(JSON.stringify(schemas[name]))));
  for (const m of msgs[topic]) {
    if (!validate(m)) {
      bad++;
      if (bad < 4) console.log(topic, JSON.stringify(validate.errors).slice(0, 300));
    }
  }
  console.log(`${topic}: ${msgs[topic].length} messages checked as foxglove.${name}`);
}
console.log(bad === 0 ? "all valid" : `${bad} invalid`);
process.exit(bad === 0 ? 0 : 1);
"""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("mcap", type=Path)
    parser.add_argument("--node-modules", type=Path, required=True)
    args = parser.parse_args()
    topics = {"/slider_crank/tf": [], "/slider_crank/scene": []}
    with args.mcap.open("rb") as f:
        for _, channel, message in make_reader(f).iter_messages(topics=list(topics)):
            topics[channel.topic].append(json.loads(message.data))
    with tempfile.TemporaryDirectory() as tmp:
        messages = Path(tmp) / "messages.json"
        messages.write_text(json.dumps(topics))
        script = args.node_modules.parent / "check_foxglove.js"
        script.write_text(CHECK)
        sys.exit(subprocess.run(["node", str(script), str(messages)], check=False).returncode)


if __name__ == "__main__":
    main()
