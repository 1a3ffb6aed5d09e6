/* transcalib report: the interactive 3-D view (report/viewer.py writes its data).
 *
 * Reads the JSON of <script id="tc-viewer-data">, draws with three.js (the vendored
 * three.min.js, inlined before this script: the global THREE) into <div id="tc-viewer">:
 * the points (image colour or depth colour), the optional extra cloud, a frustum per view,
 * the world axes and, where known, the robot frame (flange or base) of every view. OrbitControls: drag to orbit,
 * right-drag (or shift-drag) to pan, wheel to zoom. A click picks the nearest drawn point
 * on screen and shows its id, position +- std and the views that saw it.
 *
 * Frame: three.js world = the robot frame of the calibration (lengths in its unit), less
 * the offset `origin` (float32 positions near zero). Renders on demand (no animation loop).
 * `window.transcalibViewer` exposes what tests read back: stats(), screenOf(i), camera(),
 * pickAt(x, y), look(name).
 */
(function () {
  "use strict";
  const root = document.getElementById("tc-viewer");
  const info = document.getElementById("tc-viewer-info");
  const D = JSON.parse(document.getElementById("tc-viewer-data").textContent);

  function bytes(b64) {
    const s = atob(b64), out = new Uint8Array(s.length);
    for (let k = 0; k < s.length; k++) out[k] = s.charCodeAt(k);
    return out;
  }
  const f32 = (b64) => new Float32Array(bytes(b64).buffer);
  const u16 = (b64) => new Uint16Array(bytes(b64).buffer);

  function half(h) {  // IEEE 754 binary16 -> number (the stds travel as float16)
    const s = h & 0x8000 ? -1 : 1, e = (h >> 10) & 0x1f, m = h & 0x3ff;
    if (e === 0) return s * m * Math.pow(2, -24);
    if (e === 31) return m ? NaN : s * Infinity;
    return s * (1 + m / 1024) * Math.pow(2, e - 15);
  }

  const gl = document.createElement("canvas").getContext("webgl2");
  if (!gl) {  // no console error: say it on the page
    root.classList.add("tc-nogl");
    info.textContent = "This browser offers no WebGL 2: the 3-D view cannot be drawn (the figures below show the reconstruction).";
    window.transcalibViewer = {ready: false, webgl: false};
    return;
  }

  THREE.ColorManagement.enabled = false;  // colours as given: image RGB, our palette
  const renderer = new THREE.WebGLRenderer({antialias: true, preserveDrawingBuffer: true});
  renderer.outputColorSpace = THREE.LinearSRGBColorSpace;
  renderer.setPixelRatio(window.devicePixelRatio || 1);
  renderer.setClearColor(0x1e1e22);
  root.insertBefore(renderer.domElement, root.firstChild);
  const scene = new THREE.Scene();

  function cloud(c, size) {
    const g = new THREE.BufferGeometry();
    g.setAttribute("position", new THREE.BufferAttribute(f32(c.xyz), 3));
    g.setAttribute("color", new THREE.BufferAttribute(bytes(c.rgb), 3, true));
    const m = new THREE.PointsMaterial({size: size, sizeAttenuation: false, vertexColors: true});
    const p = new THREE.Points(g, m);
    scene.add(p);
    return p;
  }

  function lines(xyz, rgb) {  // segments: (2 k, 3) float32 ends, (2 k, 3) uint8 colours
    const g = new THREE.BufferGeometry();
    g.setAttribute("position", new THREE.BufferAttribute(f32(xyz), 3));
    g.setAttribute("color", new THREE.BufferAttribute(bytes(rgb), 3, true));
    const l = new THREE.LineSegments(g, new THREE.LineBasicMaterial({vertexColors: true}));
    scene.add(l);
    return l;
  }

  const layers = {points: cloud(D.points, D.point_size)};
  const P = layers.points.geometry.attributes.position.array;
  if (D.extra) layers.extra = cloud(D.extra, D.point_size);
  layers.frusta = lines(D.frusta.xyz, D.frusta.rgb);
  layers.axes = lines(D.axes.xyz, D.axes.rgb);
  if (D.frames) layers.frames = lines(D.frames.xyz, D.frames.rgb);
  const mark = new THREE.Points(new THREE.BufferGeometry(), new THREE.PointsMaterial({size: 11, sizeAttenuation: false, color: 0xff2060}));
  mark.geometry.setAttribute("position", new THREE.BufferAttribute(new Float32Array(3), 3));
  mark.visible = false;
  scene.add(mark);

  const camera = new THREE.PerspectiveCamera(50, 1, 1, 2);
  const controls = new THREE.OrbitControls(camera, renderer.domElement);
  controls.screenSpacePanning = true;

  function render() { renderer.render(scene, camera); }

  function look(name) {  // one of the page's views (viewer.py _first_views): the target is the origin
    const v = D.view[name];
    camera.up.fromArray(v.up);
    camera.position.fromArray(v.eye);
    camera.near = v.near;
    camera.far = v.far;
    camera.updateProjectionMatrix();
    controls.target.set(0, 0, 0);
    controls.update();
    render();
  }

  function resize() {
    const w = root.clientWidth, h = Math.round(Math.min(640, Math.max(320, 0.62 * w)));
    renderer.setSize(w, h);
    camera.aspect = w / h;
    camera.updateProjectionMatrix();
    render();
  }

  function screenOf(i) {  // page pixels (client coordinates) of drawn point i, or null behind the camera
    const p = new THREE.Vector3(P[3 * i], P[3 * i + 1], P[3 * i + 2]).project(camera);
    if (p.z < -1 || p.z > 1) return null;
    const r = renderer.domElement.getBoundingClientRect();
    return [r.left + (p.x + 1) / 2 * r.width, r.top + (1 - p.y) / 2 * r.height];
  }

  function nearest(x, y, radius) {  // drawn point nearest to client (x, y) within radius px (ties: nearer the eye)
    const r = renderer.domElement.getBoundingClientRect(), e = new THREE.Vector3();
    camera.updateMatrixWorld();
    const M = camera.projectionMatrix.clone().multiply(camera.matrixWorldInverse).elements;
    let best = -1, bestD = radius * radius, bestZ = Infinity;
    for (let i = 0; i < P.length / 3; i++) {
      const a = P[3 * i], b = P[3 * i + 1], c = P[3 * i + 2];
      const w = M[3] * a + M[7] * b + M[11] * c + M[15];
      if (w <= 0) continue;
      const sx = r.left + ((M[0] * a + M[4] * b + M[8] * c + M[12]) / w + 1) / 2 * r.width;
      const sy = r.top + (1 - (M[1] * a + M[5] * b + M[9] * c + M[13]) / w) / 2 * r.height;
      const d = (sx - x) * (sx - x) + (sy - y) * (sy - y);
      if (d < bestD - 2 || (d <= bestD + 2 && w < bestZ)) { best = i; bestD = Math.min(d, bestD); bestZ = w; }
    }
    return best;
  }

  const seen = bytes(D.points.seen), inlier = D.points.inlier ? bytes(D.points.inlier) : null;
  const std = D.points.std ? u16(D.points.std) : null;
  const nb = D.points.seen_bytes;

  function fmt(x, s) {  // x with as many decimals as its std warrants (2 significant digits of s)
    if (!(s > 0) || !isFinite(s)) return x.toPrecision(7);
    const d = Math.max(0, Math.min(9, 1 - Math.floor(Math.log10(s))));
    return x.toFixed(d) + " \u00b1 " + s.toFixed(d);
  }

  function describe(i) {
    const names = ["x", "y", "z"], pos = [];
    for (let k = 0; k < 3; k++) {
      const x = P[3 * i + k] + D.origin[k], s = std ? half(std[3 * i + k]) : NaN;
      pos.push(names[k] + " " + fmt(x, s));
    }
    const views = [];
    for (let j = 0; j < D.views.length; j++) if ((seen[i * nb + (j >> 3)] >> (j & 7)) & 1) views.push(D.views[j]);
    const flag = inlier ? (((inlier[i >> 3] >> (i & 7)) & 1) ? "inlier" : "outlier") : "";
    return "point " + D.points.ids[i] + ": " + pos.join(", ") + " " + D.unit + "; seen in " + views.length +
      " of " + D.views.length + " views: " + views.join(", ") + (flag ? "; " + flag : "");
  }

  function pickAt(x, y) {
    const i = nearest(x, y, 8);
    if (i < 0) {
      mark.visible = false;
      info.textContent = "no point within 8 px of the click";
    } else {
      mark.geometry.attributes.position.array.set(P.subarray(3 * i, 3 * i + 3));
      mark.geometry.attributes.position.needsUpdate = true;
      mark.visible = true;
      info.textContent = describe(i);
    }
    render();
    return i;
  }

  let down = null;  // a click is a press and release without a drag
  renderer.domElement.addEventListener("pointerdown", (e) => { down = [e.clientX, e.clientY]; });
  renderer.domElement.addEventListener("pointerup", (e) => {
    if (down && Math.hypot(e.clientX - down[0], e.clientY - down[1]) < 4 && e.button === 0) pickAt(e.clientX, e.clientY);
    down = null;
  });
  controls.addEventListener("change", render);
  window.addEventListener("resize", resize);
  for (const box of root.querySelectorAll("input[data-layer]")) {
    box.addEventListener("change", () => { const l = layers[box.dataset.layer]; if (l) { l.visible = box.checked; render(); } });
  }
  const size = root.querySelector("input[data-size]");
  if (size) size.addEventListener("input", () => { layers.points.material.size = +size.value; if (layers.extra) layers.extra.material.size = +size.value; render(); });
  for (const b of root.querySelectorAll("button[data-view]")) b.addEventListener("click", () => look(b.dataset.view));

  resize();
  look("oblique");
  window.transcalibViewer = {
    ready: true, webgl: true, revision: THREE.REVISION, screenOf: screenOf, pickAt: pickAt, look: look,
    camera: () => ({eye: camera.position.toArray(), target: controls.target.toArray()}),
    stats: () => {  // what the last frame drew (three.js counts the GL calls' primitives)
      render();
      return {points: renderer.info.render.points, lines: renderer.info.render.lines,
              cloud: layers.points.geometry.attributes.position.count,
              extra: layers.extra ? layers.extra.geometry.attributes.position.count : 0,
              frusta: D.frusta.n, frustum_lines: layers.frusta.geometry.attributes.position.count / 2,
              frames: D.frames ? D.frames.n : 0};
    },
  };
})();
