// Validate a glTF/GLB file with the Khronos validator (npm gltf-validator) and print its JSON report.
// usage: NODE_PATH=.tools/node_modules node tests/gltf_validate.js FILE
const fs = require("fs");
const validator = require("gltf-validator");
const file = process.argv[2];
validator.validateBytes(new Uint8Array(fs.readFileSync(file)), { uri: file, maxIssues: 100 })
    .then((report) => { console.log(JSON.stringify(report, null, 1)); })
    .catch((err) => { console.error("validator failed: " + err); process.exit(3); });
