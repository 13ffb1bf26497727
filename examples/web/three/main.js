// deformgl in three.js: runs an export of `deformgl export-web SCENE OUT_DIR` with the shader
// pack's ES shaders (OUT_DIR/shaders) as three.js RawShaderMaterials. URL parameters as the raw
// WebGL2 example (../main.js): data=OUT_DIR (default "data"); steps=N runs N steps, draws one
// frame and writes the result (the canvas as a PNG data URL, the timings, every error) as JSON
// into <pre id="result"> (tests/test_web_three.py reads it); without steps the page animates.
//
// The node state lives in three WebGLRenderTargets (RGBA32F, the export's compact layout: node n
// at texel (n % width, n / width), which export-web pins); every vertex of the detailed mesh
// carries the texels of its three nodes (texel1..3.i32), so the mapping shader reads the nodes
// where the export put them.
import * as THREE from "three";

const params = new URLSearchParams(location.search);
const DATA = params.get("data") || "data";
const FIXED_STEPS = params.has("steps") ? parseInt(params.get("steps"), 10) : null;
const STEPS_PER_FRAME = 10;
const errors = [];

function fail(message) {
  errors.push(message);
  document.getElementById("status").textContent = "error: " + message;
  throw new Error(message);
}

async function fetchText(path) {
  const r = await fetch(`${DATA}/${path}`);
  if (!r.ok) fail(`${DATA}/${path}: HTTP ${r.status}`);
  return r.text();
}

async function fetchArray(name, info) {
  const r = await fetch(`${DATA}/${name}`);
  if (!r.ok) fail(`${DATA}/${name}: HTTP ${r.status}`);
  const type = { f32: Float32Array, i32: Int32Array, u32: Uint32Array }[info.files[name].dtype];
  const array = new type(await r.arrayBuffer());
  const count = info.files[name].shape.reduce((a, b) => a * b, 1);
  if (array.length !== count) fail(`${name}: ${array.length} values, scene.json says ${count}`);
  return array;
}

// The pack's rule (shaders/README.md): paste each #include once, defines after the header lines.
// three.js writes the "#version 300 es" line of a GLSL3 RawShaderMaterial itself, so the pack's
// own is left out; the defines go after the precision lines as the pack asks (not through
// material.defines, which would turn `true` into "#define X true").
async function shaderSource(name, defines) {
  const seen = new Set();
  async function expand(path) {
    const out = [];
    for (const line of (await fetchText(`shaders/${path}`)).split("\n")) {
      const m = line.match(/^\s*#\s*include\s+"([^"]+)"/);
      if (!m) { out.push(line); continue; }
      if (!seen.has(m[1])) { seen.add(m[1]); out.push(...await expand(m[1])); }
    }
    return out;
  }
  const lines = await expand(name);
  if (!lines[0].startsWith("#version")) fail(`shaders/${name}: no #version line`);
  let head = 1;
  while (head < lines.length && lines[head].startsWith("precision ")) head++;
  const defs = Object.entries(defines).filter(([, v]) => v !== false && v !== null)
    .map(([k, v]) => (v === true ? `#define ${k}` : `#define ${k} ${v}`));
  return [...lines.slice(1, head), ...defs, ...lines.slice(head)].join("\n");
}

async function material(vert, frag, defines, uniforms, options = {}) {
  return new THREE.RawShaderMaterial({
    glslVersion: THREE.GLSL3,
    vertexShader: await shaderSource(vert, defines),
    fragmentShader: await shaderSource(frag, defines),
    uniforms, blending: THREE.NoBlending, ...options,
  });
}

function nearest(texture) {
  texture.minFilter = texture.magFilter = THREE.NearestFilter;
  texture.generateMipmaps = false;
  texture.needsUpdate = true;
  return texture;
}

async function main() {
  const info = JSON.parse(await fetchText("scene.json"));
  const canvas = document.getElementById("canvas");
  [canvas.width, canvas.height] = info.size;
  THREE.ColorManagement.enabled = false;  // the pack's colours are written as they are
  const renderer = new THREE.WebGLRenderer({ canvas, antialias: !!info.antialias, preserveDrawingBuffer: true,
                                             alpha: false });
  renderer.debug.onShaderError = (gl, program, vs, fs) => {
    errors.push(`shader: ${gl.getProgramInfoLog(program)} ${gl.getShaderInfoLog(vs)} ${gl.getShaderInfoLog(fs)}`);
  };
  renderer.setPixelRatio(1);
  renderer.setSize(info.size[0], info.size[1], false);
  renderer.outputColorSpace = THREE.LinearSRGBColorSpace;
  renderer.autoClear = false;
  if (!renderer.extensions.has("EXT_color_buffer_float")) fail("EXT_color_buffer_float is missing: cannot render RGBA32F");
  const { width: W, height: H } = info.texture;
  // the binding's texels (texel1..3.i32) are in the layout the export pins: compact
  if (!info.texture.compact) fail("scene.json: texture.compact is false: this page reads the compact node layout");
  const camera = new THREE.OrthographicCamera();  // unused by the pack's shaders (they take u_view_projection)

  // --- node textures: node data, three rotating RGBA32F render targets, neighbour indices
  const floatTexture = (array) => nearest(new THREE.DataTexture(array, W, H, THREE.RGBAFormat, THREE.FloatType));
  const arrayTexture = (array, integer) => {
    const t = new THREE.DataArrayTexture(array, W, H, 5);
    t.format = integer ? THREE.RGBAIntegerFormat : THREE.RGBAFormat;
    t.type = integer ? THREE.IntType : THREE.FloatType;
    t.internalFormat = integer ? "RGBA32I" : "RGBA32F";
    return nearest(t);
  };
  const node = await fetchArray("node.f32", info);
  const nodeTex = floatTexture(node);
  const targets = [0, 1, 2].map(() => new THREE.WebGLRenderTarget(W, H, {
    type: THREE.FloatType, format: THREE.RGBAFormat, minFilter: THREE.NearestFilter,
    magFilter: THREE.NearestFilter, depthBuffer: false, generateMipmaps: false }));
  const neighbours = info.files["neighbours.i32"] ? arrayTexture(await fetchArray("neighbours.i32", info), true) : null;
  const springWeights = info.files["spring_weights.f32"] ? arrayTexture(await fetchArray("spring_weights.f32", info), false) : null;
  const pulls = await fetchArray("pulls.f32", info);
  const nPulls = info.verlet.defines.PULLS;

  // one full-screen triangle (sim/fullscreen.vert places it by gl_VertexID)
  const triangle = new THREE.BufferGeometry();
  triangle.setAttribute("position", new THREE.Float32BufferAttribute(new Float32Array(9), 3));
  triangle.setDrawRange(0, 3);
  function pass(mat) {
    const scene = new THREE.Scene();
    const quad = new THREE.Mesh(triangle, mat);
    quad.frustumCulled = false;
    scene.add(quad);
    return scene;
  }

  // the start state: state_current and state_previous copied into two targets (texelFetch)
  const copy = new THREE.RawShaderMaterial({
    glslVersion: THREE.GLSL3, blending: THREE.NoBlending, depthTest: false, depthWrite: false,
    uniforms: { u_source: { value: null } },
    vertexShader: await shaderSource("sim/fullscreen.vert", {}),
    fragmentShader: "precision highp float;\nuniform highp sampler2D u_source;\nlayout(location = 0) out vec4 o_value;\n" +
      "void main() { o_value = texelFetch(u_source, ivec2(gl_FragCoord.xy), 0); }\n" });
  const copyScene = pass(copy);
  for (const [index, name] of [[0, "state_current.f32"], [1, "state_previous.f32"]]) {
    copy.uniforms.u_source.value = floatTexture(await fetchArray(name, info));
    renderer.setRenderTarget(targets[index]);
    renderer.render(copyScene, camera);
  }

  // --- the Verlet pass (sim/fullscreen.vert + sim/verlet.frag), uniforms as the export gives them
  const verletUniforms = { u_position: { value: null }, u_previous: { value: null }, u_node: { value: nodeTex } };
  for (const [k, v] of Object.entries(info.verlet.uniforms)) verletUniforms[k] = { value: v };
  if (neighbours) verletUniforms.u_neighbours = { value: neighbours };
  if (springWeights) verletUniforms.u_weights = { value: springWeights };
  if (nPulls) verletUniforms.u_pull_force = { value: pulls.subarray(0, 3 * nPulls) };
  const verlet = await material("sim/fullscreen.vert", "sim/verlet.frag", info.verlet.defines, verletUniforms,
                                { depthTest: false, depthWrite: false });
  const stepScene = pass(verlet);
  let [current, previous, spare] = [0, 1, 2];
  let stepsDone = 0;

  function step(n) {
    const rows = pulls.length / (3 * Math.max(nPulls, 1));
    for (let i = 0; i < n; i++) {
      if (nPulls) {
        const k = Math.min(stepsDone, rows - 1) * 3 * nPulls;
        verletUniforms.u_pull_force.value = pulls.subarray(k, k + 3 * nPulls);
      }
      verletUniforms.u_position.value = targets[current].texture;
      verletUniforms.u_previous.value = targets[previous].texture;
      renderer.setRenderTarget(targets[spare]);
      renderer.render(stepScene, camera);
      [current, previous, spare] = [spare, current, previous];
      stepsDone++;
    }
  }

  // --- the detailed mesh: a three.js Mesh whose vertex attributes are the binding, drawn with the
  // pack's mapping shaders (render/mapped_mesh.vert + .frag)
  const geometry = new THREE.BufferGeometry();
  const attributes = [["in_texel1", "texel1.i32", 2], ["in_texel2", "texel2.i32", 2], ["in_texel3", "texel3.i32", 2],
                      ["in_weights", "weights.f32", 3], ["in_offset", "offset.f32", 3],
                      ["in_offset_world", "offset_world.f32", 3], ["in_normal", "normal.f32", 3],
                      ["in_normal_world", "normal_world.f32", 3]];
  if (info.mapping.defines.CURVATURE) attributes.push(["in_curvature", "curvature.f32", 1]);
  for (const [name, file, size] of attributes) {
    const data = await fetchArray(file, info);
    const attribute = file.endsWith(".i32") ? new THREE.Int32BufferAttribute(data, size) : new THREE.BufferAttribute(data, size);
    if (file.endsWith(".i32")) attribute.gpuType = THREE.IntType;  // ivec2: vertexAttribIPointer
    geometry.setAttribute(name, attribute);
  }
  geometry.setIndex(new THREE.BufferAttribute(await fetchArray("faces.u32", info), 1));
  const meshUniforms = { u_position: { value: targets[current].texture },
                         u_view_projection: { value: info.view.view_projection_column_major },
                         u_eye: { value: info.view.eye } };
  for (const [k, v] of Object.entries(info.lighting)) meshUniforms[k] = { value: v };
  const mapping = await material("render/mapped_mesh.vert", "render/mapped_mesh.frag", info.mapping.defines,
                                 meshUniforms, { side: THREE.DoubleSide });  // DoubleSide: no culling, as deformgl
  const mesh = new THREE.Mesh(geometry, mapping);
  mesh.frustumCulled = false;  // the shader places the vertices; three.js has no positions to bound
  const meshScene = new THREE.Scene();
  meshScene.add(mesh);
  renderer.setClearColor(new THREE.Color(...info.background), 1.0);

  function draw() {
    meshUniforms.u_position.value = targets[current].texture;
    renderer.setRenderTarget(null);
    renderer.clear(true, true, false);
    renderer.render(meshScene, camera);
  }

  const status = document.getElementById("status");
  if (FIXED_STEPS !== null) {
    // timings without the first step and the first frame (they include the shaders' compile)
    const texel = new Float32Array(4), pixel = new Uint8Array(4);
    const sync = () => renderer.readRenderTargetPixels(targets[current], 0, 0, 1, 1, texel);
    if (FIXED_STEPS > 0) { step(1); sync(); }
    const t0 = performance.now();
    step(FIXED_STEPS - stepsDone);
    sync();
    const t1 = performance.now();
    let frameMs = Infinity;
    const gl = renderer.getContext();
    for (let i = 0; i < 5; i++) {
      const t = performance.now();
      draw();
      gl.readPixels(0, 0, 1, 1, gl.RGBA, gl.UNSIGNED_BYTE, pixel);  // wait for the frame
      if (i > 0) frameMs = Math.min(frameMs, performance.now() - t);
    }
    for (let e = gl.getError(); e !== gl.NO_ERROR; e = gl.getError()) errors.push(`GL error 0x${e.toString(16)}`);
    const result = { steps: stepsDone, step_ms: (t1 - t0) / Math.max(FIXED_STEPS - 1, 1), frame_ms: frameMs,
                     three: THREE.REVISION, renderer: gl.getParameter(gl.RENDERER), errors,
                     png: canvas.toDataURL("image/png") };
    document.getElementById("result").textContent = JSON.stringify(result);
    status.textContent = `${stepsDone} steps: ${result.step_ms.toFixed(3)} ms per step, frame ${result.frame_ms.toFixed(1)} ms (three.js r${THREE.REVISION})`;
    return;
  }
  let last = performance.now();
  renderer.setAnimationLoop(() => {
    step(STEPS_PER_FRAME);
    draw();
    const now = performance.now();
    status.textContent = `${stepsDone} steps, ${(now - last).toFixed(1)} ms per frame of ${STEPS_PER_FRAME} steps (three.js r${THREE.REVISION})` +
      (errors.length ? ` | ${errors.length} errors: ${errors[0]}` : "");
    last = now;
  });
}

main().catch((e) => {
  if (!errors.includes(String(e.message))) errors.push(String(e.message || e));
  document.getElementById("result").textContent = JSON.stringify({ errors });
});
