// The SPZ reference library (nianticlabs/spz built to WebAssembly as @adobe/spz, with its extensions) for
// tests/test_spz_gltf.py (through tests/other_tools.py):
//   decode IN.spz OUTDIR TO          IN as loadSpz gives it with UnpackOptions.to = TO (a CoordinateSystem name or
//                                    UNSPECIFIED): OUTDIR/meta.json and one little-endian float32 file per attribute
//   reencode IN.spz OUT.spz TO VER   IN loaded with to = TO, saved raw (from = UNSPECIFIED, no extension): a file
//                                    whose bytes hold TO's axes and do not say so
// The library's own log lines go to stdout/stderr; the results go to files.
import fs from 'fs';
import path from 'path';
import createSpzModule from '@adobe/spz';

const [command, input, output, to, version] = process.argv.slice(2);
const spz = await createSpzModule();
const system = spz.CoordinateSystem[to];
if (system === undefined) throw new Error(`unknown coordinate system ${to}`);
const cloud = spz.loadSpzFromBuffer(new Uint8Array(fs.readFileSync(input)), { to: system });
if (!cloud.numPoints) throw new Error(`the reference could not load ${input}`);

if (command === 'decode') {
  fs.mkdirSync(output, { recursive: true });
  const extensions = [];
  const count = typeof cloud.extensions.size === 'function' ? cloud.extensions.size() : cloud.extensions.length;
  for (let i = 0; i < count; i++) {
    const e = typeof cloud.extensions.get === 'function' ? cloud.extensions.get(i) : cloud.extensions[i];
    extensions.push({ type: e.extensionType.value >>> 0, coordinateSystem: e.coordinateSystem?.value ?? null });
  }
  fs.writeFileSync(path.join(output, 'meta.json'), JSON.stringify(
    { numPoints: cloud.numPoints, shDegree: cloud.shDegree, extensions }));
  for (const name of ['positions', 'scales', 'rotations', 'alphas', 'colors', 'sh']) {
    const values = Float32Array.from(cloud[name]);
    fs.writeFileSync(path.join(output, `${name}.f32`), Buffer.from(values.buffer));
  }
} else if (command === 'reencode') {
  const raw = {
    numPoints: cloud.numPoints, shDegree: cloud.shDegree, antialiased: cloud.antialiased, extensions: [],
    positions: Float32Array.from(cloud.positions), scales: Float32Array.from(cloud.scales),
    rotations: Float32Array.from(cloud.rotations), alphas: Float32Array.from(cloud.alphas),
    colors: Float32Array.from(cloud.colors), sh: Float32Array.from(cloud.sh),
  };
  const bytes = spz.saveSpzToBuffer(raw, {
    version: Number(version), from: spz.CoordinateSystem.UNSPECIFIED, sh1Bits: 5, shRestBits: 4 });
  fs.writeFileSync(output, bytes);
} else {
  throw new Error(`unknown command ${command}`);
}
