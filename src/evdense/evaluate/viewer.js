// evdense mesh viewer: textured triangle meshes side by side, one linked orbit camera.
// Plain WebGL (2 when there is one, else 1), no library, nothing fetched: the page embeds the
// meshes (base64 float32 corner positions and texture coordinates) and their atlases (PNG data
// URIs) in a <script type="application/json" id="evdense-meshes"> element.
// Panels whose meshes share a frame (data.meshes[i].frame, a key of data.views) share one camera.
// Drag: orbit. Shift-drag or right-drag: pan. Wheel: zoom. Double-click: back to the start view.
"use strict";
(function () {
  const data = JSON.parse(document.getElementById("evdense-meshes").textContent);

  // --- small vector helpers (arrays of 3) ---------------------------------------------------
  const sub = (a, b) => [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
  const add = (a, b) => [a[0] + b[0], a[1] + b[1], a[2] + b[2]];
  const mul = (a, s) => [a[0] * s, a[1] * s, a[2] * s];
  const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
  const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
  const norm = (a) => mul(a, 1 / Math.max(Math.hypot(a[0], a[1], a[2]), 1e-12));
  function rotate(v, axis, ang) {  // Rodrigues: v turned by ang about the unit axis
    const c = Math.cos(ang), s = Math.sin(ang);
    return add(add(mul(v, c), mul(cross(axis, v), s)), mul(axis, dot(axis, v) * (1 - c)));
  }

  // --- cameras, one per frame: eye, target, up, vertical field of view ---------------------
  const cams = {};
  for (const [key, v] of Object.entries(data.views))
    cams[key] = { start: v, eye: v.eye.slice(), target: v.target.slice(), up: norm(v.up),
                  scale: v.scale, views: [] };
  function redraw(cam) { for (const v of cam.views) v.draw(); }

  function viewMatrix(cam) {  // world -> OpenGL eye coordinates (x right, y up, looking down -z)
    const f = norm(sub(cam.target, cam.eye));
    const r = norm(cross(f, cam.up));
    const u = cross(r, f);
    const e = cam.eye;
    return [r[0], u[0], -f[0], 0, r[1], u[1], -f[1], 0, r[2], u[2], -f[2], 0,
            -dot(r, e), -dot(u, e), dot(f, e), 1];
  }
  function projMatrix(cam, aspect, near, far) {
    const t = 1 / Math.tan((cam.start.fov_y_deg * Math.PI) / 360);
    return [t / aspect, 0, 0, 0, 0, t, 0, 0, 0, 0, (far + near) / (near - far), -1,
            0, 0, (2 * far * near) / (near - far), 0];
  }
  function matmul(a, b) {  // column-major 4x4
    const o = new Array(16).fill(0);
    for (let c = 0; c < 4; c++)
      for (let r = 0; r < 4; r++)
        for (let k = 0; k < 4; k++) o[c * 4 + r] += a[k * 4 + r] * b[c * 4 + k];
    return o;
  }

  // --- one panel ------------------------------------------------------------------------------
  function decode(b64) {
    const bin = atob(b64);
    const bytes = new Uint8Array(bin.length);
    for (let i = 0; i < bin.length; i++) bytes[i] = bin.charCodeAt(i);
    return new Float32Array(bytes.buffer);
  }
  const VS = `attribute vec3 pos; attribute vec2 uv; uniform mat4 mvp; varying vec2 vuv;
    void main() { vuv = uv; gl_Position = mvp * vec4(pos, 1.0); }`;
  const FS = `precision mediump float; uniform sampler2D tex; varying vec2 vuv;
    void main() { gl_FragColor = vec4(texture2D(tex, vec2(vuv.x, 1.0 - vuv.y)).rgb, 1.0); }`;

  function makeView(canvas, mesh, cam) {
    const gl = canvas.getContext("webgl", { preserveDrawingBuffer: true, antialias: true });
    if (!gl) { canvas.replaceWith(document.createTextNode("WebGL is not available")); return; }
    function shader(type, src) {
      const s = gl.createShader(type); gl.shaderSource(s, src); gl.compileShader(s); return s;
    }
    const prog = gl.createProgram();
    gl.attachShader(prog, shader(gl.VERTEX_SHADER, VS));
    gl.attachShader(prog, shader(gl.FRAGMENT_SHADER, FS));
    gl.linkProgram(prog);
    gl.useProgram(prog);
    const pos = decode(mesh.positions), uv = decode(mesh.uvs);
    for (const [name, arr, size] of [["pos", pos, 3], ["uv", uv, 2]]) {
      const buf = gl.createBuffer();
      gl.bindBuffer(gl.ARRAY_BUFFER, buf);
      gl.bufferData(gl.ARRAY_BUFFER, arr, gl.STATIC_DRAW);
      const loc = gl.getAttribLocation(prog, name);
      gl.enableVertexAttribArray(loc);
      gl.vertexAttribPointer(loc, size, gl.FLOAT, false, 0, 0);
    }
    const tex = gl.createTexture();
    gl.bindTexture(gl.TEXTURE_2D, tex);  // grey until the atlas has loaded
    gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGBA, 1, 1, 0, gl.RGBA, gl.UNSIGNED_BYTE,
                  new Uint8Array([128, 128, 128, 255]));
    for (const [k, v] of [[gl.TEXTURE_MIN_FILTER, gl.LINEAR], [gl.TEXTURE_MAG_FILTER, gl.LINEAR],
                          [gl.TEXTURE_WRAP_S, gl.CLAMP_TO_EDGE], [gl.TEXTURE_WRAP_T, gl.CLAMP_TO_EDGE]])
      gl.texParameteri(gl.TEXTURE_2D, k, v);
    const img = new Image();
    img.onload = () => {
      gl.bindTexture(gl.TEXTURE_2D, tex);
      gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGBA, gl.RGBA, gl.UNSIGNED_BYTE, img);
      view.draw();
      document.body.dataset.loaded = String(Number(document.body.dataset.loaded || 0) + 1);
    };
    img.src = mesh.texture;
    const mvpLoc = gl.getUniformLocation(prog, "mvp");
    const count = pos.length / 3;
    gl.enable(gl.DEPTH_TEST);
    const view = {
      draw() {
        const w = canvas.clientWidth, h = canvas.clientHeight;
        if (canvas.width !== w || canvas.height !== h) { canvas.width = w; canvas.height = h; }
        gl.viewport(0, 0, w, h);
        gl.clearColor(0.12, 0.12, 0.14, 1);
        gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
        const d = Math.hypot(...sub(cam.target, cam.eye));
        const mvp = matmul(projMatrix(cam, w / h, 0.01 * cam.scale, d + 4 * cam.scale), viewMatrix(cam));
        gl.uniformMatrix4fv(mvpLoc, false, new Float32Array(mvp));
        gl.drawArrays(gl.TRIANGLES, 0, count);
      },
    };
    cam.views.push(view);
    attachControls(canvas, cam);
  }

  // --- mouse: orbit about the target, pan, zoom; all panels follow ---------------------------
  function attachControls(canvas, cam) {
    let last = null, panning = false;
    canvas.addEventListener("contextmenu", (e) => e.preventDefault());
    canvas.addEventListener("mousedown", (e) => {
      last = [e.clientX, e.clientY]; panning = e.button === 2 || e.shiftKey;
    });
    window.addEventListener("mouseup", () => { last = null; });
    window.addEventListener("mousemove", (e) => {
      if (!last) return;
      const dx = e.clientX - last[0], dy = e.clientY - last[1];
      last = [e.clientX, e.clientY];
      const back = sub(cam.eye, cam.target);
      const f = norm(mul(back, -1)), r = norm(cross(f, cam.up)), u = cross(r, f);
      if (panning) {
        const s = Math.hypot(...back) / canvas.clientHeight;
        const shift = add(mul(r, -dx * s), mul(u, dy * s));
        cam.eye = add(cam.eye, shift); cam.target = add(cam.target, shift);
      } else {
        let b = rotate(back, cam.up, -dx * 0.01);
        const r2 = norm(cross(mul(b, -1), cam.up));
        b = rotate(b, r2, -dy * 0.01);
        cam.eye = add(cam.target, b);
      }
      redraw(cam);
    });
    canvas.addEventListener("wheel", (e) => {
      e.preventDefault();
      const back = sub(cam.eye, cam.target);
      cam.eye = add(cam.target, mul(back, Math.exp(e.deltaY * 0.001)));
      redraw(cam);
    }, { passive: false });
    canvas.addEventListener("dblclick", () => {
      cam.eye = cam.start.eye.slice(); cam.target = cam.start.target.slice(); redraw(cam);
    });
  }

  const grid = document.getElementById("evdense-grid");
  for (const mesh of data.meshes) {
    const panel = document.createElement("figure");
    const canvas = document.createElement("canvas");
    const cap = document.createElement("figcaption");
    cap.textContent = mesh.label;
    panel.append(canvas, cap);
    grid.append(panel);
    makeView(canvas, mesh, cams[mesh.frame]);
  }
  for (const cam of Object.values(cams)) redraw(cam);
})();
