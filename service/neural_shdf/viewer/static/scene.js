// The 3-D view: one three.js mesh drawn with a colour per triangle, orbit controls, picking.
//
// Colours: the palette, the heat map and the swatches are sRGB (as the API's `color` and CSS).
// three.js treats vertex colours as linear light and encodes its output to sRGB, so every
// colour is converted with the sRGB transfer function before it becomes a vertex colour.
import * as THREE from 'three';
import { OrbitControls } from 'three/addons/controls/OrbitControls.js';

const NO_VALUE = [110, 110, 110];
const PLAIN = [200, 200, 200];
const DIM = 0.3;
/** Viridis at 5 stops (thin = dark blue, thick = yellow), sRGB. */
const RAMP = [[68, 1, 84], [59, 82, 139], [33, 145, 140], [94, 201, 98], [253, 231, 37]];
/** Per up axis: the up vector and the two horizontal axes (front first, DCC convention). */
const AXES = {
  y: { up: [0, 1, 0], horizontal: [[0, 0, 1], [1, 0, 0]] },
  z: { up: [0, 0, 1], horizontal: [[0, -1, 0], [1, 0, 0]] },
};

/** sRGB component in [0, 1] to linear light. */
export function srgbToLinear(c) {
  return c <= 0.04045 ? c / 12.92 : ((c + 0.055) / 1.055) ** 2.4;
}

/** Linear component in [0, 1] to sRGB. */
export function linearToSrgb(c) {
  return c <= 0.0031308 ? c * 12.92 : 1.055 * c ** (1 / 2.4) - 0.055;
}

/** Vertex colours are linear 16-bit integers: 8 bits would band in the darks (and lose
 * the palette's exact values), floats cost twice the upload. */
const LINEAR_MAX = 65535;
/** Linear value of each sRGB byte, in LINEAR_MAX units. */
const LINEAR = Uint16Array.from({ length: 256 }, (_, i) => Math.round(srgbToLinear(i / 255) * LINEAR_MAX));

/** RGB bytes (sRGB) of a value in [0, 1] on the heat map ramp, interpolated as CSS does. */
export function heatColor(value) {
  if (!Number.isFinite(value)) return NO_VALUE;
  const x = Math.min(Math.max(value, 0), 1) * (RAMP.length - 1);
  const i = Math.min(Math.floor(x), RAMP.length - 2);
  const t = x - i;
  return RAMP[i].map((c, k) => Math.round(c + (RAMP[i + 1][k] - c) * t));
}

/** CSS gradient of the heat map ramp, for the legend. */
export function heatGradient() {
  return `linear-gradient(to right, ${RAMP.map((c) => `rgb(${c.join(',')})`).join(', ')})`;
}

/** '#rrggbb' -> [r, g, b]. */
export function parseHex(hex) {
  const n = parseInt(hex.slice(1), 16);
  return [(n >> 16) & 255, (n >> 8) & 255, n & 255];
}

/** Linear RGB of sRGB bytes (`bytes`: r, g, b, r, g, b, ...), scaled by `scale`. */
function linearOf(bytes, scale = 1) {
  return Uint16Array.from(bytes, (c) => Math.round(LINEAR[c] * scale));
}

export class MeshView {
  constructor(canvas) {
    this.canvas = canvas;
    this.renderer = new THREE.WebGLRenderer({ canvas, antialias: true });
    this.renderer.setPixelRatio(Math.min(window.devicePixelRatio || 1, 2));
    this.scene = new THREE.Scene();
    this.scene.background = new THREE.Color(0xf3f4f6);
    this.camera = new THREE.PerspectiveCamera(40, 1, 0.01, 1000);
    this.scene.add(new THREE.HemisphereLight(0xffffff, 0x8d8d8d, 1.6));
    const light = new THREE.DirectionalLight(0xffffff, 1.6);
    light.position.set(0.5, 1, 2);
    this.camera.add(light);  // the light follows the view
    this.scene.add(this.camera);
    this.controls = new OrbitControls(this.camera, canvas);
    this.controls.addEventListener('change', () => this.requestRender());
    this.mesh = null;
    this.drawPending = false;
    this.faceOrigin = null;
    this.up = 'y';
    this.lit = true;
    this.materials = {
      lit: new THREE.MeshLambertMaterial({ vertexColors: true, side: THREE.DoubleSide }),
      flat: new THREE.MeshBasicMaterial({ vertexColors: true, side: THREE.DoubleSide }),
    };
    new ResizeObserver(() => this.resize()).observe(canvas.parentElement);
    this.resize();
  }

  resize() {
    const { clientWidth: width, clientHeight: height } = this.canvas.parentElement;
    if (!width || !height) return;
    this.renderer.setSize(width, height, false);
    this.camera.aspect = width / height;
    this.camera.updateProjectionMatrix();
    this.render();
  }

  /** Draw now (tests read the pixels back right after). */
  render() {
    this.renderer.render(this.scene, this.camera);
  }

  /**
   * Draw in the next animation frame, once however often it is asked: a recolouring and
   * a selection in one task, or many orbit events, cost one draw of the whole mesh.
   */
  requestRender() {
    if (this.drawPending) return;
    this.drawPending = true;
    requestAnimationFrame(() => {
      this.drawPending = false;
      this.render();
    });
  }

  /** Resolves after the browser has presented a frame with the current colours. */
  presented() {
    this.requestRender();
    // Frame callbacks run in the order asked: this one runs after the draw above.
    return new Promise((resolve) => requestAnimationFrame(() => resolve(performance.now())));
  }

  /**
   * Show new geometry: triangles as stored by the service (`triangles`: 3 vertex indices each),
   * `faceOrigin`: the input face of each triangle. Triangles never share a drawn vertex, so a
   * colour per triangle never blends into its neighbours.
   */
  setGeometry({ positions, triangles, faceOrigin }) {
    if (this.mesh) {
      this.scene.remove(this.mesh);
      this.mesh.geometry.dispose();
    }
    const count = faceOrigin.length;
    const vertexNormals = smoothNormals(positions, triangles);
    const position = new Float32Array(count * 9);
    const normal = new Float32Array(count * 9);
    for (let corner = 0; corner < count * 3; corner++) {
      const v = triangles[corner] * 3;
      const o = corner * 3;
      position[o] = positions[v]; position[o + 1] = positions[v + 1]; position[o + 2] = positions[v + 2];
      normal[o] = vertexNormals[v]; normal[o + 1] = vertexNormals[v + 1]; normal[o + 2] = vertexNormals[v + 2];
    }
    const geometry = new THREE.BufferGeometry();
    geometry.setAttribute('position', new THREE.BufferAttribute(position, 3));
    geometry.setAttribute('normal', new THREE.BufferAttribute(normal, 3));
    const color = new THREE.BufferAttribute(new Uint16Array(count * 9).fill(LINEAR[PLAIN[0]]), 3, true);
    color.setUsage(THREE.DynamicDrawUsage);
    geometry.setAttribute('color', color);
    geometry.computeBoundingSphere();
    geometry.computeBoundingBox();
    this.mesh = new THREE.Mesh(geometry, this.lit ? this.materials.lit : this.materials.flat);
    this.scene.add(this.mesh);
    this.faceOrigin = faceOrigin;
    this.frame();
  }

  /** Shade with the lights (true) or draw the colours flat, exactly as the swatches. */
  setLit(lit) {
    this.lit = lit;
    if (this.mesh) this.mesh.material = lit ? this.materials.lit : this.materials.flat;
    this.render();
  }

  /** The up axis of the mesh's file ('y' or 'z'); the camera is framed again. */
  setUp(axis) {
    this.up = axis === 'z' ? 'z' : 'y';
    if (this.mesh) this.frame();
  }

  /**
   * Point the camera at the whole mesh with the up axis up, looking across its wider
   * horizontal side (the front unless the mesh is deeper than wide), a little from above
   * and to the side, at a distance that fits its bounding sphere.
   */
  frame() {
    const geometry = this.mesh.geometry;
    const { center, radius } = geometry.boundingSphere;
    const size = geometry.boundingBox.getSize(new THREE.Vector3());
    const axes = AXES[this.up];
    const up = new THREE.Vector3(...axes.up);
    let [front, side] = axes.horizontal.map((axis) => new THREE.Vector3(...axis));
    const extent = (axis) => Math.abs(size.dot(axis));
    if (extent(front) > extent(side)) [front, side] = [side, front.negate()];
    const direction = front.addScaledVector(side, 0.3).addScaledVector(up, 0.35).normalize();
    const halfHeight = Math.tan(THREE.MathUtils.degToRad(this.camera.fov / 2));
    const halfView = Math.min(halfHeight, halfHeight * this.camera.aspect);
    const distance = (1.1 * (radius || 1)) / halfView;
    this.camera.near = distance / 100;
    this.camera.far = distance * 100;
    this.camera.up.copy(up);
    this.camera.position.copy(center).add(direction.multiplyScalar(distance));
    this.camera.updateProjectionMatrix();
    // OrbitControls takes the up axis from the camera when it is made.
    this.controls.dispose();
    this.controls = new OrbitControls(this.camera, this.canvas);
    this.controls.addEventListener('change', () => this.requestRender());
    this.controls.target.copy(center);
    this.controls.update();
    this.render();
  }

  /**
   * Colour every triangle by part: `labels` per input face, `palette` sRGB bytes per label,
   * `unlabeled` sRGB bytes of a negative label; all but the `selected` part dimmed when one is.
   */
  paintParts(labels, palette, unlabeled, selected = -1) {
    const parts = palette.length / 3;
    const bright = linearOf(palette);
    const dim = linearOf(palette, DIM);
    const none = linearOf(unlabeled, selected >= 0 ? DIM : 1);
    const out = this.mesh.geometry.getAttribute('color').array;
    const origin = this.faceOrigin;
    for (let t = 0; t < origin.length; t++) {
      const label = labels[origin[t]];
      let source = none, i = 0;
      if (label >= 0 && label < parts) {
        source = selected >= 0 && label !== selected ? dim : bright;
        i = label * 3;
      }
      const r = source[i], g = source[i + 1], b = source[i + 2];
      const o = t * 9;
      out[o] = out[o + 3] = out[o + 6] = r;
      out[o + 1] = out[o + 4] = out[o + 7] = g;
      out[o + 2] = out[o + 5] = out[o + 8] = b;
    }
    this.mesh.geometry.getAttribute('color').needsUpdate = true;
  }

  /** Colour every triangle by its input face's ShDF on the heat map ramp. */
  paintShdf(values) {
    const color = this.mesh.geometry.getAttribute('color');
    const out = color.array;
    const origin = this.faceOrigin;
    for (let t = 0; t < origin.length; t++) {
      const [r, g, b] = heatColor(values[origin[t]]);
      const o = t * 9;
      out[o] = out[o + 3] = out[o + 6] = LINEAR[r];
      out[o + 1] = out[o + 4] = out[o + 7] = LINEAR[g];
      out[o + 2] = out[o + 5] = out[o + 8] = LINEAR[b];
    }
    color.needsUpdate = true;
  }

  paintPlain() {
    const color = this.mesh.geometry.getAttribute('color');
    color.array.fill(LINEAR[PLAIN[0]]);
    color.needsUpdate = true;
  }

  /** Draw only the triangles whose input face's label `visible(label)` accepts (null: all). */
  setVisibility(labels, visible) {
    const geometry = this.mesh.geometry;
    if (!visible) {
      geometry.setIndex(null);
      return;
    }
    const origin = this.faceOrigin;
    const corners = new Uint32Array(origin.length * 3);
    let n = 0;
    for (let t = 0; t < origin.length; t++) {
      if (visible(labels[origin[t]])) {
        corners[n++] = t * 3; corners[n++] = t * 3 + 1; corners[n++] = t * 3 + 2;
      }
    }
    geometry.setIndex(new THREE.BufferAttribute(corners.slice(0, n), 1));
  }

  /** The input face under a canvas pixel, or -1. */
  pick(clientX, clientY) {
    if (!this.mesh) return -1;
    const rect = this.canvas.getBoundingClientRect();
    const pointer = new THREE.Vector2(
      ((clientX - rect.left) / rect.width) * 2 - 1,
      -((clientY - rect.top) / rect.height) * 2 + 1,
    );
    const raycaster = new THREE.Raycaster();
    raycaster.setFromCamera(pointer, this.camera);
    const geometry = this.mesh.geometry;  // the mesh is never moved: world = its own space
    const triangle = nearestTriangle(
      geometry.getAttribute('position').array, geometry.index?.array ?? null, raycaster.ray,
    );
    return triangle >= 0 ? this.faceOrigin[triangle] : -1;
  }

  /** sRGB bytes of each triangle's colour (tests compare them with the service's colours). */
  triangleColors() {
    const colors = this.mesh.geometry.getAttribute('color').array;
    const out = new Uint8Array(this.faceOrigin.length * 3);
    for (let t = 0; t < this.faceOrigin.length; t++) {
      for (let k = 0; k < 3; k++) out[t * 3 + k] = Math.round(linearToSrgb(colors[t * 9 + k] / LINEAR_MAX) * 255);
    }
    return out;
  }
}

/**
 * The drawn triangle a ray meets first (both sides count), or -1: one tight loop over the
 * corner positions (three.js's general ray cast costs several times more at 100k
 * triangles). `corners`: the index of the visible corners, or null for all.
 */
function nearestTriangle(position, corners, ray) {
  const { x: ox, y: oy, z: oz } = ray.origin;
  const { x: dx, y: dy, z: dz } = ray.direction;
  const count = corners ? corners.length / 3 : position.length / 9;
  let best = Infinity;
  let found = -1;
  for (let k = 0; k < count; k++) {
    const t = corners ? corners[3 * k] / 3 : k;  // corners of triangle t: 3t, 3t+1, 3t+2
    const a = 9 * t;
    const ax = position[a], ay = position[a + 1], az = position[a + 2];
    const e1x = position[a + 3] - ax, e1y = position[a + 4] - ay, e1z = position[a + 5] - az;
    const e2x = position[a + 6] - ax, e2y = position[a + 7] - ay, e2z = position[a + 8] - az;
    // Moller-Trumbore: p = d x e2, det = e1 . p.
    const px = dy * e2z - dz * e2y, py = dz * e2x - dx * e2z, pz = dx * e2y - dy * e2x;
    const det = e1x * px + e1y * py + e1z * pz;
    if (det > -1e-12 && det < 1e-12) continue;  // parallel to the triangle
    const inv = 1 / det;
    const sx = ox - ax, sy = oy - ay, sz = oz - az;
    const u = (sx * px + sy * py + sz * pz) * inv;
    if (u < 0 || u > 1) continue;
    const qx = sy * e1z - sz * e1y, qy = sz * e1x - sx * e1z, qz = sx * e1y - sy * e1x;
    const v = (dx * qx + dy * qy + dz * qz) * inv;
    if (v < 0 || u + v > 1) continue;
    const distance = (e2x * qx + e2y * qy + e2z * qz) * inv;
    if (distance > 0 && distance < best) {
      best = distance;
      found = t;
    }
  }
  return found;
}

/** Area-weighted vertex normals of an indexed triangle mesh. */
function smoothNormals(positions, triangles) {
  const normals = new Float32Array(positions.length);
  for (let i = 0; i < triangles.length; i += 3) {
    const a = triangles[i] * 3, b = triangles[i + 1] * 3, c = triangles[i + 2] * 3;
    const ux = positions[b] - positions[a], uy = positions[b + 1] - positions[a + 1], uz = positions[b + 2] - positions[a + 2];
    const vx = positions[c] - positions[a], vy = positions[c + 1] - positions[a + 1], vz = positions[c + 2] - positions[a + 2];
    const nx = uy * vz - uz * vy, ny = uz * vx - ux * vz, nz = ux * vy - uy * vx;
    for (const v of [a, b, c]) { normals[v] += nx; normals[v + 1] += ny; normals[v + 2] += nz; }
  }
  for (let v = 0; v < normals.length; v += 3) {
    const length = Math.hypot(normals[v], normals[v + 1], normals[v + 2]) || 1;
    normals[v] /= length; normals[v + 1] /= length; normals[v + 2] /= length;
  }
  return normals;
}
