// Validate one glTF file with the Khronos glTF-Validator (npm package gltf-validator) and print its report as JSON.
// Usage: NODE_PATH=<folder with node_modules/gltf-validator> node gltf_validate.js FILE.glb
const fs = require("fs");
const validator = require("gltf-validator");

const file = process.argv[2];
const bytes = new Uint8Array(fs.readFileSync(file));
validator
  .validateBytes(bytes, { maxIssues: 200, writeTimestamp: false })
  .then((report) => {
    process.stdout.write(JSON.stringify(report));
  })
  .catch((error) => {
    process.stderr.write(String(error));
    process.exit(3);
  });
