// Validate glTF/GLB files with the Khronos glTF validator; prints one JSON report per file.
// Usage: node validate_gltf.js FILE...
const fs = require("fs");
const validator = require("gltf-validator");

async function main() {
  const reports = [];
  for (const file of process.argv.slice(2)) {
    const report = await validator.validateBytes(new Uint8Array(fs.readFileSync(file)), {
      maxIssues: 50,
    });
    reports.push({ file, issues: report.issues });
  }
  process.stdout.write(JSON.stringify(reports));
}

main().catch((error) => {
  process.stderr.write(String(error));
  process.exit(1);
});
