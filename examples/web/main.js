// deformgl web example: runs an export of `deformgl export-web SCENE OUT_DIR` with the shader
// pack's ES shaders (OUT_DIR/shaders) in WebGL2. URL parameters: data=OUT_DIR (default "data");
// steps=N runs N steps, draws one frame and writes the result (the canvas as a PNG data URL,
// the timings and every WebGL error) as JSON into <pre id="result"> (the test reads it);
// without steps the page animates and a node can be dragged with the mouse.
"use strict";

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
  const buffer = await r.arrayBuffer();
  const type = { f32: Float32Array, i32: Int32Array, u32: Uint32Array }[info.files[name].dtype];
  const array = new type(buffer);
  const count = info.files[name].shape.reduce((a, b) => a * b, 1);
  if (array.length !== count) fail(`${name}: ${array.length} values, scene.json says ${count}`);
  return array;
}

// The pack's rule (shaders/README.md): paste each #include once, defines after the header lines.
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
  let head = 1;
  while (head < lines.length && lines[head].startsWith("precision ")) head++;
  const defs = Object.entries(defines).filter(([, v]) => v !== false && v !== null)
    .map(([k, v]) => (v === true ? `#define ${k}` : `#define ${k} ${v}`));
  return [...lines.slice(0, head), ...defs, ...lines.slice(head)].join("\n");
}

function compile(gl, type, source, name) {
  const s = gl.createShader(type);
  gl.shaderSource(s, source);
  gl.compileShader(s);
  if (!gl.getShaderParameter(s, gl.COMPILE_STATUS)) fail(`${name}: ${gl.getShaderInfoLog(s)}`);
  return s;
}

async function program(gl, vert, frag, defines) {
  const p = gl.createProgram();
  gl.attachShader(p, compile(gl, gl.VERTEX_SHADER, await shaderSource(vert, defines), vert));
  gl.attachShader(p, compile(gl, gl.FRAGMENT_SHADER, await shaderSource(frag, defines), frag));
  gl.linkProgram(p);
  if (!gl.getProgramParameter(p, gl.LINK_STATUS)) fail(`${vert}+${frag}: ${gl.getProgramInfoLog(p)}`);
  return p;
}

function setUniform(gl, p, name, value) {
  const loc = gl.getUniformLocation(p, name);
  if (loc === null) return;
  if (typeof value === "number") gl.uniform1f(loc, value);
  else if (value.length === 3) gl.uniform3fv(loc, value);
  else if (value.length === 16) gl.uniformMatrix4fv(loc, false, value);
}

function checkError(gl, where) {
  for (let e = gl.getError(); e !== gl.NO_ERROR; e = gl.getError()) errors.push(`${where}: GL error 0x${e.toString(16)}`);
}

function floatTexture(gl, w, h, data) {
  const t = gl.createTexture();
  gl.bindTexture(gl.TEXTURE_2D, t);
  gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGBA32F, w, h, 0, gl.RGBA, gl.FLOAT, data);
  for (const [k, v] of [[gl.TEXTURE_MIN_FILTER, gl.NEAREST], [gl.TEXTURE_MAG_FILTER, gl.NEAREST],
                        [gl.TEXTURE_WRAP_S, gl.CLAMP_TO_EDGE], [gl.TEXTURE_WRAP_T, gl.CLAMP_TO_EDGE]]) {
    gl.texParameteri(gl.TEXTURE_2D, k, v);
  }
  return t;
}

function invert(m) {  // 4x4 column-major inverse (cofactors)
  const inv = new Float64Array(16);
  inv[0] = m[5]*m[10]*m[15]-m[5]*m[11]*m[14]-m[9]*m[6]*m[15]+m[9]*m[7]*m[14]+m[13]*m[6]*m[11]-m[13]*m[7]*m[10];
  inv[4] = -m[4]*m[10]*m[15]+m[4]*m[11]*m[14]+m[8]*m[6]*m[15]-m[8]*m[7]*m[14]-m[12]*m[6]*m[11]+m[12]*m[7]*m[10];
  inv[8] = m[4]*m[9]*m[15]-m[4]*m[11]*m[13]-m[8]*m[5]*m[15]+m[8]*m[7]*m[13]+m[12]*m[5]*m[11]-m[12]*m[7]*m[9];
  inv[12] = -m[4]*m[9]*m[14]+m[4]*m[10]*m[13]+m[8]*m[5]*m[14]-m[8]*m[6]*m[13]-m[12]*m[5]*m[10]+m[12]*m[6]*m[9];
  inv[1] = -m[1]*m[10]*m[15]+m[1]*m[11]*m[14]+m[9]*m[2]*m[15]-m[9]*m[3]*m[14]-m[13]*m[2]*m[11]+m[13]*m[3]*m[10];
  inv[5] = m[0]*m[10]*m[15]-m[0]*m[11]*m[14]-m[8]*m[2]*m[15]+m[8]*m[3]*m[14]+m[12]*m[2]*m[11]-m[12]*m[3]*m[10];
  inv[9] = -m[0]*m[9]*m[15]+m[0]*m[11]*m[13]+m[8]*m[1]*m[15]-m[8]*m[3]*m[13]-m[12]*m[1]*m[11]+m[12]*m[3]*m[9];
  inv[13] = m[0]*m[9]*m[14]-m[0]*m[10]*m[13]-m[8]*m[1]*m[14]+m[8]*m[2]*m[13]+m[12]*m[1]*m[10]-m[12]*m[2]*m[9];
  inv[2] = m[1]*m[6]*m[15]-m[1]*m[7]*m[14]-m[5]*m[2]*m[15]+m[5]*m[3]*m[14]+m[13]*m[2]*m[7]-m[13]*m[3]*m[6];
  inv[6] = -m[0]*m[6]*m[15]+m[0]*m[7]*m[14]+m[4]*m[2]*m[15]-m[4]*m[3]*m[14]-m[12]*m[2]*m[7]+m[12]*m[3]*m[6];
  inv[10] = m[0]*m[5]*m[15]-m[0]*m[7]*m[13]-m[4]*m[1]*m[15]+m[4]*m[3]*m[13]+m[12]*m[1]*m[7]-m[12]*m[3]*m[5];
  inv[14] = -m[0]*m[5]*m[14]+m[0]*m[6]*m[13]+m[4]*m[1]*m[14]-m[4]*m[2]*m[13]-m[12]*m[1]*m[6]+m[12]*m[2]*m[5];
  inv[3] = -m[1]*m[6]*m[11]+m[1]*m[7]*m[10]+m[5]*m[2]*m[11]-m[5]*m[3]*m[10]-m[9]*m[2]*m[7]+m[9]*m[3]*m[6];
  inv[7] = m[0]*m[6]*m[11]-m[0]*m[7]*m[10]-m[4]*m[2]*m[11]+m[4]*m[3]*m[10]+m[8]*m[2]*m[7]-m[8]*m[3]*m[6];
  inv[11] = -m[0]*m[5]*m[11]+m[0]*m[7]*m[9]+m[4]*m[1]*m[11]-m[4]*m[3]*m[9]-m[8]*m[1]*m[7]+m[8]*m[3]*m[5];
  inv[15] = m[0]*m[5]*m[10]-m[0]*m[6]*m[9]-m[4]*m[1]*m[10]+m[4]*m[2]*m[9]+m[8]*m[1]*m[6]-m[8]*m[2]*m[5];
  const det = m[0]*inv[0]+m[1]*inv[4]+m[2]*inv[8]+m[3]*inv[12];
  return inv.map((v) => v / det);
}

function transform(m, v) {  // column-major 4x4 times (x, y, z, w)
  return [0, 1, 2, 3].map((r) => m[r]*v[0] + m[4+r]*v[1] + m[8+r]*v[2] + m[12+r]*v[3]);
}

async function main() {
  const info = JSON.parse(await fetchText("scene.json"));
  const canvas = document.getElementById("canvas");
  [canvas.width, canvas.height] = info.size;
  const gl = canvas.getContext("webgl2", { antialias: !!info.antialias, preserveDrawingBuffer: true, alpha: false });
  if (!gl) fail("no WebGL2");
  if (!gl.getExtension("EXT_color_buffer_float")) fail("EXT_color_buffer_float is missing: cannot render RGBA32F");
  const { width: W, height: H } = info.texture;

  // --- node textures: node data, 3 rotating states, neighbour indices (compact, not dense)
  const node = await fetchArray("node.f32", info);
  const nodeTex = floatTexture(gl, W, H, node);
  const state = [floatTexture(gl, W, H, await fetchArray("state_current.f32", info)),
                 floatTexture(gl, W, H, await fetchArray("state_previous.f32", info)),
                 floatTexture(gl, W, H, null)];
  const fbos = state.map((t) => {
    const f = gl.createFramebuffer();
    gl.bindFramebuffer(gl.FRAMEBUFFER, f);
    gl.framebufferTexture2D(gl.FRAMEBUFFER, gl.COLOR_ATTACHMENT0, gl.TEXTURE_2D, t, 0);
    if (gl.checkFramebufferStatus(gl.FRAMEBUFFER) !== gl.FRAMEBUFFER_COMPLETE) fail("RGBA32F framebuffer incomplete");
    return f;
  });
  let neighbours = null;
  if (info.files["neighbours.i32"]) {
    neighbours = gl.createTexture();
    gl.bindTexture(gl.TEXTURE_2D_ARRAY, neighbours);
    gl.texImage3D(gl.TEXTURE_2D_ARRAY, 0, gl.RGBA32I, W, H, 5, 0, gl.RGBA_INTEGER, gl.INT,
                  await fetchArray("neighbours.i32", info));
    gl.texParameteri(gl.TEXTURE_2D_ARRAY, gl.TEXTURE_MIN_FILTER, gl.NEAREST);
    gl.texParameteri(gl.TEXTURE_2D_ARRAY, gl.TEXTURE_MAG_FILTER, gl.NEAREST);
  }
  let springWeights = null;  // a material's calibrated lattice: per-spring weights (SPRING_WEIGHTS)
  if (info.files["spring_weights.f32"]) {
    springWeights = gl.createTexture();
    gl.bindTexture(gl.TEXTURE_2D_ARRAY, springWeights);
    gl.texImage3D(gl.TEXTURE_2D_ARRAY, 0, gl.RGBA32F, W, H, 5, 0, gl.RGBA, gl.FLOAT,
                  await fetchArray("spring_weights.f32", info));
    gl.texParameteri(gl.TEXTURE_2D_ARRAY, gl.TEXTURE_MIN_FILTER, gl.NEAREST);
    gl.texParameteri(gl.TEXTURE_2D_ARRAY, gl.TEXTURE_MAG_FILTER, gl.NEAREST);
  }
  const pulls = await fetchArray("pulls.f32", info);
  const nPulls = info.verlet.defines.PULLS;

  // --- the Verlet pass (sim/fullscreen.vert + sim/verlet.frag)
  const verlet = await program(gl, "sim/fullscreen.vert", "sim/verlet.frag", info.verlet.defines);
  gl.useProgram(verlet);
  for (const [k, v] of Object.entries(info.verlet.uniforms)) {
    const loc = gl.getUniformLocation(verlet, k);
    if (k === "u_width_log2") gl.uniform1i(loc, v);
    else if (k === "u_strides") gl.uniform3iv(loc, v);
    else setUniform(gl, verlet, k, v);
  }
  gl.uniform1i(gl.getUniformLocation(verlet, "u_position"), 0);
  gl.uniform1i(gl.getUniformLocation(verlet, "u_previous"), 1);
  gl.uniform1i(gl.getUniformLocation(verlet, "u_node"), 2);
  if (neighbours) gl.uniform1i(gl.getUniformLocation(verlet, "u_neighbours"), 3);
  if (springWeights) gl.uniform1i(gl.getUniformLocation(verlet, "u_weights"), 4);
  const pullLoc = nPulls ? gl.getUniformLocation(verlet, "u_pull_force") : null;
  const emptyVao = gl.createVertexArray();
  let [current, previous, spare] = [0, 1, 2];
  let stepsDone = 0;

  function step(n) {
    gl.useProgram(verlet);
    gl.bindVertexArray(emptyVao);
    gl.disable(gl.DEPTH_TEST);
    gl.viewport(0, 0, W, H);
    gl.activeTexture(gl.TEXTURE2); gl.bindTexture(gl.TEXTURE_2D, nodeTex);
    if (neighbours) { gl.activeTexture(gl.TEXTURE3); gl.bindTexture(gl.TEXTURE_2D_ARRAY, neighbours); }
    if (springWeights) { gl.activeTexture(gl.TEXTURE4); gl.bindTexture(gl.TEXTURE_2D_ARRAY, springWeights); }
    const rows = pulls.length / (3 * Math.max(nPulls, 1));
    for (let i = 0; i < n; i++) {
      if (pullLoc) {
        const k = Math.min(stepsDone, rows - 1) * 3 * nPulls;
        gl.uniform3fv(pullLoc, pulls.subarray(k, k + 3 * nPulls));
      }
      gl.activeTexture(gl.TEXTURE0); gl.bindTexture(gl.TEXTURE_2D, state[current]);
      gl.activeTexture(gl.TEXTURE1); gl.bindTexture(gl.TEXTURE_2D, state[previous]);
      gl.bindFramebuffer(gl.FRAMEBUFFER, fbos[spare]);
      gl.drawArrays(gl.TRIANGLES, 0, 3);
      [current, previous, spare] = [spare, current, previous];
      stepsDone++;
    }
  }

  // --- the mapped mesh (render/mapped_mesh.vert + .frag): the bound vertex attributes
  const mapping = await program(gl, "render/mapped_mesh.vert", "render/mapped_mesh.frag", info.mapping.defines);
  const vao = gl.createVertexArray();
  gl.bindVertexArray(vao);
  const attributes = [["in_texel1", "texel1.i32", 2], ["in_texel2", "texel2.i32", 2], ["in_texel3", "texel3.i32", 2],
                      ["in_weights", "weights.f32", 3], ["in_offset", "offset.f32", 3],
                      ["in_offset_world", "offset_world.f32", 3], ["in_normal", "normal.f32", 3],
                      ["in_normal_world", "normal_world.f32", 3], ["in_curvature", "curvature.f32", 1]];
  for (const [name, file, size] of attributes) {
    const loc = gl.getAttribLocation(mapping, name);
    if (loc < 0) continue;  // in_curvature exists only with CURVATURE
    const buffer = gl.createBuffer();
    gl.bindBuffer(gl.ARRAY_BUFFER, buffer);
    gl.bufferData(gl.ARRAY_BUFFER, await fetchArray(file, info), gl.STATIC_DRAW);
    gl.enableVertexAttribArray(loc);
    if (file.endsWith(".i32")) gl.vertexAttribIPointer(loc, size, gl.INT, 0, 0);
    else gl.vertexAttribPointer(loc, size, gl.FLOAT, false, 0, 0);
  }
  const faces = await fetchArray("faces.u32", info);
  const ibo = gl.createBuffer();
  gl.bindBuffer(gl.ELEMENT_ARRAY_BUFFER, ibo);
  gl.bufferData(gl.ELEMENT_ARRAY_BUFFER, faces, gl.STATIC_DRAW);
  gl.bindVertexArray(null);
  gl.useProgram(mapping);
  gl.uniform1i(gl.getUniformLocation(mapping, "u_position"), 0);
  setUniform(gl, mapping, "u_view_projection", info.view.view_projection_column_major);
  setUniform(gl, mapping, "u_eye", info.view.eye);
  for (const [k, v] of Object.entries(info.lighting)) setUniform(gl, mapping, k, v);

  function draw() {
    gl.bindFramebuffer(gl.FRAMEBUFFER, null);
    gl.viewport(0, 0, canvas.width, canvas.height);
    gl.clearColor(...info.background, 1.0);
    gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
    gl.enable(gl.DEPTH_TEST);
    gl.useProgram(mapping);
    gl.activeTexture(gl.TEXTURE0); gl.bindTexture(gl.TEXTURE_2D, state[current]);
    gl.bindVertexArray(vao);
    gl.drawElements(gl.TRIANGLES, faces.length, gl.UNSIGNED_INT, 0);
    gl.bindVertexArray(null);
  }
  checkError(gl, "set-up");

  // --- dragging: the picked node is fixed (flag bit 2) and written into both states (no velocity)
  const vp = info.view.view_projection_column_major, inverseVp = invert(vp);
  let drag = null;
  function readState(index) {
    const out = new Float32Array(W * H * 4);
    gl.bindFramebuffer(gl.FRAMEBUFFER, fbos[index]);
    gl.readPixels(0, 0, W, H, gl.RGBA, gl.FLOAT, out);
    return out;
  }
  function mouseNdc(event) {
    const r = canvas.getBoundingClientRect();
    return [2 * (event.clientX - r.left) / r.width - 1, 1 - 2 * (event.clientY - r.top) / r.height];
  }
  canvas.addEventListener("mousedown", (event) => {
    const [mx, my] = mouseNdc(event), s = readState(current);
    let best = null;
    for (let t = 0; t < W * H; t++) {
      if ((node[4 * t + 1] & 1) === 0) continue;  // not an existing node
      const c = transform(vp, [s[4 * t], s[4 * t + 1], s[4 * t + 2], 1]);
      const d = Math.hypot(c[0] / c[3] - mx, c[1] / c[3] - my);
      if (best === null || d < best.d) best = { d, t, ndcZ: c[2] / c[3], w: s[4 * t + 3] };
    }
    if (best === null || best.d > 0.1) return;
    drag = best;
    const texel = node.slice(4 * drag.t, 4 * drag.t + 4);
    texel[1] = (texel[1] | 2);
    gl.bindTexture(gl.TEXTURE_2D, nodeTex);
    gl.texSubImage2D(gl.TEXTURE_2D, 0, drag.t % W, Math.floor(drag.t / W), 1, 1, gl.RGBA, gl.FLOAT, texel);
  });
  canvas.addEventListener("mousemove", (event) => {
    if (!drag) return;
    const [mx, my] = mouseNdc(event);
    const p = transform(inverseVp, [mx, my, drag.ndcZ, 1]);
    const texel = new Float32Array([p[0] / p[3], p[1] / p[3], p[2] / p[3], drag.w]);
    for (const tex of [state[current], state[previous]]) {
      gl.bindTexture(gl.TEXTURE_2D, tex);
      gl.texSubImage2D(gl.TEXTURE_2D, 0, drag.t % W, Math.floor(drag.t / W), 1, 1, gl.RGBA, gl.FLOAT, texel);
    }
  });
  window.addEventListener("mouseup", () => {
    if (!drag) return;
    gl.bindTexture(gl.TEXTURE_2D, nodeTex);
    gl.texSubImage2D(gl.TEXTURE_2D, 0, drag.t % W, Math.floor(drag.t / W), 1, 1, gl.RGBA, gl.FLOAT,
                     node.slice(4 * drag.t, 4 * drag.t + 4));
    drag = null;
  });

  const status = document.getElementById("status");
  if (FIXED_STEPS !== null) {
    // timings without the first step and the first frame (they include SwiftShader's shader JIT)
    const pixel = new Uint8Array(4), position = new Float32Array(4);
    const sync = () => { gl.bindFramebuffer(gl.FRAMEBUFFER, fbos[current]); gl.readPixels(0, 0, 1, 1, gl.RGBA, gl.FLOAT, position); };
    if (FIXED_STEPS > 0) { step(1); sync(); }
    const t0 = performance.now();
    step(FIXED_STEPS - stepsDone);
    sync();
    const t1 = performance.now();
    let frameMs = Infinity;
    for (let i = 0; i < 5; i++) {
      const t = performance.now();
      draw();
      gl.readPixels(0, 0, 1, 1, gl.RGBA, gl.UNSIGNED_BYTE, pixel);  // wait for the frame
      if (i > 0) frameMs = Math.min(frameMs, performance.now() - t);
    }
    const t2 = performance.now();
    checkError(gl, "steps and frame");
    const result = { steps: stepsDone, step_ms: (t1 - t0) / Math.max(FIXED_STEPS - 1, 1), frame_ms: frameMs,
                     frames_ms_total: t2 - t1,
                     renderer: gl.getParameter(gl.RENDERER), float_linear: !!gl.getExtension("OES_texture_float_linear"),
                     errors, png: canvas.toDataURL("image/png") };
    document.getElementById("result").textContent = JSON.stringify(result);
    status.textContent = `${stepsDone} steps: ${result.step_ms.toFixed(3)} ms per step, frame ${result.frame_ms.toFixed(1)} ms`;
    return;
  }
  // for tests and the console: steps done, the dragged node, a node's position and its screen point
  window.deformglPage = {
    steps: () => stepsDone,
    dragged: () => (drag ? drag.t : null),
    position: (t) => Array.from(readState(current).slice(4 * t, 4 * t + 3)),
    ndc: (t) => { const s = readState(current), c = transform(vp, [s[4 * t], s[4 * t + 1], s[4 * t + 2], 1]);
                  return [c[0] / c[3], c[1] / c[3]]; },
  };
  let last = performance.now();
  function frame() {
    step(STEPS_PER_FRAME);
    draw();
    checkError(gl, "frame");
    const now = performance.now();
    status.textContent = `${stepsDone} steps, ${(now - last).toFixed(1)} ms per frame of ${STEPS_PER_FRAME} steps` +
      (errors.length ? ` | ${errors.length} GL errors: ${errors[0]}` : "");
    last = now;
    requestAnimationFrame(frame);
  }
  requestAnimationFrame(frame);
}

main().catch((e) => {
  if (!errors.includes(String(e.message))) errors.push(String(e.message || e));
  document.getElementById("result").textContent = JSON.stringify({ errors });
});
