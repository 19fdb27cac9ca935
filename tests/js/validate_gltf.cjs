// Prints the Khronos glTF validator's report of one .glb as JSON (tests/other_tools.py).
const fs = require('fs');
const validator = require('gltf-validator');
validator.validateBytes(new Uint8Array(fs.readFileSync(process.argv[2])), { maxIssues: 1000 })
  .then((report) => { process.stdout.write(JSON.stringify(report)); })
  .catch((error) => { process.stderr.write(String(error) + '\n'); process.exit(1); });
