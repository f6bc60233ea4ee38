// The service's REST API as the viewer uses it (same origin).

/** An error the service answered, with its standard body {"error": {code, message, detail}}. */
export class ServiceError extends Error {
  constructor(status, code, message) {
    super(message);
    this.name = 'ServiceError';
    this.status = status;
    this.code = code;
  }

  /** A one-line heading a person understands, from the HTTP status. */
  get title() {
    return {
      400: 'Bad request',
      404: 'Not found',
      408: 'Upload stalled',
      413: 'Too large',
      415: 'Unsupported format',
      422: 'Unusable mesh or parameters',
      503: 'Service unavailable',
      504: 'Timed out',
    }[this.status] || (this.status ? `Service error ${this.status}` : 'Network error');
  }
}

function errorFromBody(status, text) {
  try {
    const body = JSON.parse(text);
    if (body && body.error) return new ServiceError(status, body.error.code, body.error.message);
  } catch (_) { /* not the service's error shape */ }
  return new ServiceError(status, 'http_error', text ? text.slice(0, 300) : `HTTP ${status}`);
}

export async function checked(response) {
  if (!response.ok) throw errorFromBody(response.status, await response.text());
  return response;
}

/**
 * POST /v1/meshes with upload progress (fetch cannot report it, XMLHttpRequest can).
 * Resolves to {status: 200, body: UploadResult} or {status: 202, body: Job}.
 */
export function uploadMesh(file, method, onProgress) {
  return new Promise((resolve, reject) => {
    const form = new FormData();
    form.append('file', file, file.name);
    if (method) form.append('method', method);
    const xhr = new XMLHttpRequest();
    xhr.open('POST', '/v1/meshes');
    xhr.upload.onprogress = (event) => {
      if (event.lengthComputable) onProgress(event.loaded / event.total);
    };
    xhr.onload = () => {
      if (xhr.status === 200 || xhr.status === 202) {
        resolve({ status: xhr.status, body: JSON.parse(xhr.responseText) });
      } else {
        reject(errorFromBody(xhr.status, xhr.responseText));
      }
    };
    xhr.onerror = () => reject(new ServiceError(0, 'network', 'the service did not answer the upload'));
    xhr.send(form);
  });
}

const sleep = (ms) => new Promise((resolve) => setTimeout(resolve, ms));

/** Poll GET /v1/jobs/{id} until it succeeds (resolves to the job) or fails (throws). */
export async function waitForJob(job, onProgress, intervalMs = 300) {
  for (;;) {
    onProgress(job.progress || 0, job.state);
    if (job.state === 'succeeded') return job;
    if (job.state === 'failed') {
      const error = job.error || { code: 'job_failed', message: 'the job failed' };
      throw new ServiceError(422, error.code, error.message);
    }
    await sleep(intervalMs);
    job = await (await checked(await fetch(`/v1/jobs/${job.job_id}`))).json();
  }
}

export async function getMesh(meshId) {
  return (await checked(await fetch(`/v1/meshes/${meshId}`))).json();
}

/** GET /v1/meshes/{id}/geometry: {positions, triangles, faceOrigin, inputFaces}. */
export async function getGeometry(meshId) {
  const buffer = await (await checked(await fetch(`/v1/meshes/${meshId}/geometry`))).arrayBuffer();
  const header = new DataView(buffer, 0, 20);
  const magic = String.fromCharCode(...new Uint8Array(buffer, 0, 4));
  if (magic !== 'NSHG' || header.getUint32(4, true) !== 1) {
    throw new ServiceError(0, 'bad_geometry', 'the service sent geometry in an unknown layout');
  }
  const vertexCount = header.getUint32(8, true);
  const triangleCount = header.getUint32(12, true);
  const inputFaces = header.getUint32(16, true);
  let offset = 20;
  const positions = new Float32Array(buffer, offset, vertexCount * 3);
  offset += positions.byteLength;
  const triangles = new Uint32Array(buffer, offset, triangleCount * 3);
  offset += triangles.byteLength;
  const faceOrigin = new Uint32Array(buffer, offset, triangleCount);
  return { positions, triangles, faceOrigin, inputFaces };
}

/**
 * GET /v1/meshes/{id}/shdf as float32 per input face (NaN: face without triangles), waiting
 * for the job when a large mesh's ShDF is still being computed.
 */
export async function getShdf(meshId, method, onJobProgress = () => {}) {
  const query = new URLSearchParams({ format: 'f32', method });
  for (;;) {
    const response = await checked(await fetch(`/v1/meshes/${meshId}/shdf?${query}`));
    if (response.status !== 202) return new Float32Array(await response.arrayBuffer());
    await waitForJob(await response.json(), onJobProgress);
  }
}

/** GET the segmentation as a GLB (`style`: colored or parts) for the same parameters. */
export async function getGlb(meshId, style, request) {
  const url = `/v1/meshes/${meshId}/segmentation/${style}.glb?${segmentQuery(request)}`;
  const response = await checked(await fetch(url));
  if (response.status === 202) {
    throw new ServiceError(202, 'not_ready', 'the ShDF is still being computed; try again shortly');
  }
  return response.blob();
}

const LABEL_TYPES = { int8: Int8Array, int16: Int16Array, int32: Int32Array };

/**
 * The bytes of a base64 string: the browser's own decoder where it has one (one native
 * pass), else atob and a plain loop (a per-character callback cost ms at 100k faces).
 */
export function base64Bytes(base64) {
  if (typeof Uint8Array.fromBase64 === 'function') return Uint8Array.fromBase64(base64);
  const text = atob(base64);
  const bytes = new Uint8Array(text.length);
  for (let i = 0; i < text.length; i++) bytes[i] = text.charCodeAt(i);
  return bytes;
}

/** Decode base64 little-endian integers of type `dtype` (int8/16/32) to an Int32Array. */
export function decodeIntegers(base64, dtype) {
  const bytes = base64Bytes(base64);  // a new buffer at offset 0: aligned for any view
  const Type = LABEL_TYPES[dtype];
  const values = new Type(bytes.buffer, 0, bytes.length / Type.BYTES_PER_ELEMENT);
  return values instanceof Int32Array ? values : Int32Array.from(values);
}

/** Decode the compact labels of a Segmentation (labels_format=base64) to an Int32Array. */
export function decodeLabels(body) {
  if (body.labels) return Int32Array.from(body.labels);
  return decodeIntegers(body.labels_base64, body.labels_dtype);
}

/** Leaf per input face of a Segmentation's `hierarchy` (list or base64 form). */
export function decodeLeafLabels(tree) {
  if (tree.leaf_labels) return Int32Array.from(tree.leaf_labels);
  return decodeIntegers(tree.leaf_labels_base64, tree.leaf_labels_dtype);
}

/**
 * POST /v1/segment; `signal` aborts a request a newer one superseded. When the service must
 * first (re)compute the ShDF of a large mesh it answers with a job: wait for it, then ask again.
 */
export async function segment(request, signal, onJobProgress = () => {}) {
  for (;;) {
    const response = await checked(await fetch('/v1/segment', {
      method: 'POST',
      headers: { 'content-type': 'application/json' },
      body: JSON.stringify({ ...request, labels_format: 'base64' }),
      signal,
    }));
    const body = await response.json();
    if (response.status !== 202) return body;
    await waitForJob(body, onJobProgress);
    signal.throwIfAborted();
  }
}

/** Query string of the GLB routes for the same segmentation parameters. */
export function segmentQuery(request) {
  const query = new URLSearchParams();
  for (const [key, value] of Object.entries(request)) {
    if (key !== 'mesh_id' && value !== null && value !== undefined) query.set(key, String(value));
  }
  return query.toString();
}

/** GET /v1/labelers, every page: the stored part labellers ({labeler_id, label_names, ...}). */
export async function listLabelers() {
  const labelers = [];
  let offset = 0;
  while (offset !== null && offset !== undefined) {
    const page = await (await checked(await fetch(`/v1/labelers?offset=${offset}`))).json();
    labelers.push(...page.labelers);
    offset = page.next_offset;
  }
  return labelers;
}

/** POST /v1/labelers: upload a labeller file (checked by the service); its description. */
export async function uploadLabeler(file) {
  const form = new FormData();
  form.append('file', file, file.name);
  return (await checked(await fetch('/v1/labelers', { method: 'POST', body: form }))).json();
}

/** Confidence per input face of named parts (Float32Array; NaN: no triangles), or null. */
export function decodeConfidence(body) {
  if (body.confidence_base64) {
    const bytes = base64Bytes(body.confidence_base64);
    return new Float32Array(bytes.buffer, 0, bytes.length / 4);
  }
  if (body.confidence) return Float32Array.from(body.confidence, (v) => (v === null ? NaN : v));
  return null;
}
