// Validates a glTF/GLB file with the Khronos glTF-Validator (npm package
// `gltf-validator`) and prints its report as JSON on stdout.
// Usage: node gltf_validate.js VALIDATOR_PREFIX FILE.glb
// (VALIDATOR_PREFIX is the folder given to `npm install --prefix`.)
const path = require("path");
const fs = require("fs");
const validator = require(path.join(process.argv[2], "node_modules", "gltf-validator"));
const data = new Uint8Array(fs.readFileSync(process.argv[3]));
validator
  .validateBytes(data, { maxIssues: 100 })
  .then((report) => {
    console.log(JSON.stringify(report));
  })
  .catch((e) => {
    console.error("gltf-validator failed: " + e);
    process.exit(2);
  });
