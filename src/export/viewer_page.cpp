// The viewer page. Conventions it relies on (docs/formats.md):
//  - the GLB holds our OpenCV world under a root node rotated 180 degrees about
//    x (F = diag(1,-1,-1)); an OpenCV camera's axes are an OpenGL camera's
//    rotated by the same F, so a camera-to-world C becomes F * C * F in three.js;
//  - normalised intrinsics (fx/W, fy/H, cx/W, cy/H) give the projection
//    directly, whatever the window size: a W x H window reproduces the
//    rasterizer's W x H image;
//  - COLOR_0 is linear: the shader turns it back into the display values our
//    rasterizer composites, and blends them back to front by centroid depth
//    (the rasterizer's order). Triangles are drawn hard-edged (the window
//    function's sharp limit).
#include "viewer_page.h"

namespace flat::exporter {

const char* viewer_index_html() {
  return R"FLATPAGE(<!DOCTYPE html>
<!-- FLAT-C++ viewer (docs/formats.md, "Viewer"). URL: ?camera=K, or
     ?c2w=<16 numbers, row-major OpenCV camera-to-world>&fx=..&fy=..&cx=..&cy=..
     (intrinsics normalised by the image size); &bg=RRGGBB (background);
     &show=mesh (start on the opaque mesh, when the folder has one). -->
<html>
<head>
<meta charset="utf-8">
<title>FLAT viewer</title>
<style>html, body { margin: 0; height: 100%; overflow: hidden; } canvas { display: block; }
#error { position: absolute; top: 0; left: 8px; color: #f44; font: 14px monospace; white-space: pre-wrap; }
#toggle { position: absolute; top: 8px; right: 8px; font: 13px sans-serif; }</style>
</head>
<body>
<script src="three.min.js"></script>
<script src="OrbitControls.js"></script>
<script src="GLTFLoader.js"></script>
<script src="scene_glb.js"></script>
<script src="mesh_glb.js"></script>
<script src="cameras.js"></script>
<script>
"use strict";
var params = new URLSearchParams(window.location.search);
var NEAR = 0.01;  // metres, the rasterizer's near plane

function showError(message) {
  document.title = "FLAT viewer: error: " + message;
  var pre = document.createElement("pre");
  pre.id = "error";
  pre.textContent = message;
  document.body.appendChild(pre);
}

function numbers(text, count, name) {
  var values = String(text).split(",").map(Number);
  if (values.length !== count || values.some(function (v) { return !isFinite(v); }))
    throw new Error(name + " must be " + count + " comma-separated numbers, got '" + text + "'");
  return values;
}

// {c2w: 16 numbers row-major (OpenCV), intrinsics: [fx, fy, cx, cy] normalised}, or null.
function startCamera() {
  if (params.has("c2w")) {
    var k = ["fx", "fy", "cx", "cy"].map(function (key) {
      if (!params.has(key)) throw new Error("c2w= needs fx, fy, cx and cy too (normalised intrinsics)");
      return numbers(params.get(key), 1, key)[0];
    });
    if (k[0] <= 0 || k[1] <= 0) throw new Error("fx and fy must be positive");
    return {c2w: numbers(params.get("c2w"), 16, "c2w"), intrinsics: k};
  }
  var cams = (window.FLAT_CAMERAS || {cameras: []}).cameras;
  if (params.has("camera")) {
    var i = Number(params.get("camera"));
    if (!(Number.isInteger(i) && i >= 0 && i < cams.length))
      throw new Error("camera=" + params.get("camera") + ": this viewer has " + cams.length + " start cameras");
    return {c2w: [].concat.apply([], cams[i].c2w), intrinsics: cams[i].intrinsics,
            aspect: cams[i].width / cams[i].height};
  }
  return cams.length ? {c2w: [].concat.apply([], cams[0].c2w), intrinsics: cams[0].intrinsics,
                        aspect: cams[0].width / cams[0].height} : null;
}

// The intrinsics are normalised by the camera's image: the canvas keeps that
// image's aspect (letterboxed in the window), so a 5:3 view is never
// stretched to a 4:3 window. Without a start camera it fills the window.
var viewAspect = null;
function fitCanvas() {
  var w = window.innerWidth, h = window.innerHeight;
  if (viewAspect > 0) {
    if (w / h > viewAspect) w = Math.round(h * viewAspect);
    else h = Math.round(w / viewAspect);
  }
  renderer.setSize(w, h);
  renderer.domElement.style.margin = Math.floor((window.innerHeight - h) / 2) + "px " +
                                     Math.floor((window.innerWidth - w) / 2) + "px";
}

// OpenCV intrinsics -> OpenGL projection (camera looks down -z, y up, NDC
// [-1,1] spans the image edges, pixel centres at +0.5 on both sides).
function projection(k, far) {
  var fx = k[0], fy = k[1], cx = k[2], cy = k[3];
  return new THREE.Matrix4().set(
    2 * fx, 0, 1 - 2 * cx, 0,
    0, 2 * fy, 2 * cy - 1, 0,
    0, 0, -(far + NEAR) / (far - NEAR), -2 * far * NEAR / (far - NEAR),
    0, 0, -1, 0);
}

function decodeBase64(text) {
  var binary = atob(text), bytes = new Uint8Array(binary.length);
  for (var i = 0; i < binary.length; ++i) bytes[i] = binary.charCodeAt(i);
  return bytes.buffer;
}

var renderer = new THREE.WebGLRenderer({antialias: true, preserveDrawingBuffer: true});
renderer.setPixelRatio(window.devicePixelRatio);
renderer.setSize(window.innerWidth, window.innerHeight);
renderer.setClearColor(new THREE.Color("#" + (params.get("bg") || "000000").replace(/^#/, "")), 1);
document.body.appendChild(renderer.domElement);
var scene = new THREE.Scene();
var camera = new THREE.PerspectiveCamera();
var intrinsics, controls, mesh, centroids, baseIndex, bounds = new THREE.Sphere();

// Linear COLOR_0 -> display (sRGB) values, blended as our rasterizer does.
var material = new THREE.ShaderMaterial({
  vertexShader: [
    "attribute vec4 rgba;",
    "varying vec4 vRgba;",
    "void main() {",
    "  vRgba = rgba;",
    "  gl_Position = projectionMatrix * modelViewMatrix * vec4(position, 1.0);",
    "}"].join("\n"),
  fragmentShader: [
    "varying vec4 vRgba;",
    "vec3 toSrgb(vec3 c) {",
    "  return mix(c * 12.92, 1.055 * pow(c, vec3(1.0 / 2.4)) - 0.055, step(0.0031308, c));",
    "}",
    "void main() { gl_FragColor = vec4(toSrgb(clamp(vRgba.rgb, 0.0, 1.0)), vRgba.a); }"].join("\n"),
  transparent: true, depthWrite: false, side: THREE.DoubleSide});

function draw() {
  if (!mesh) return;
  var distance = camera.position.distanceTo(bounds.center);
  camera.projectionMatrix.copy(projection(intrinsics, Math.max(2 * (distance + bounds.radius), 10 * NEAR)));
  camera.projectionMatrixInverse.getInverse(camera.projectionMatrix);
  renderer.render(scene, camera);
}

var drawPending = false;
function requestDraw() {
  if (drawPending) return;
  drawPending = true;
  requestAnimationFrame(function () { drawPending = false; draw(); });
}

// Back to front by the view depth of each triangle's centroid (a counting
// sort on 16-bit depth keys: linear time for millions of triangles).
function sortTriangles() {
  camera.updateMatrixWorld();
  var view = new THREE.Matrix4().getInverse(camera.matrixWorld).multiply(mesh.matrixWorld).elements;
  var n = centroids.length / 3, z = new Float32Array(n), lo = Infinity, hi = -Infinity, i;
  for (i = 0; i < n; ++i) {
    z[i] = view[2] * centroids[3 * i] + view[6] * centroids[3 * i + 1] + view[10] * centroids[3 * i + 2] + view[14];
    lo = Math.min(lo, z[i]);
    hi = Math.max(hi, z[i]);
  }
  var bins = 65536, start = new Uint32Array(bins + 1), key = new Uint32Array(n);
  var scale = (bins - 1) / Math.max(hi - lo, 1e-20);
  for (i = 0; i < n; ++i) { key[i] = Math.floor((z[i] - lo) * scale); start[key[i] + 1]++; }
  for (i = 0; i < bins; ++i) start[i + 1] += start[i];
  var index = mesh.geometry.index;  // view z grows towards the camera: lowest key first
  for (i = 0; i < n; ++i) {
    var slot = start[key[i]]++;
    index.array[3 * slot] = baseIndex[3 * i];
    index.array[3 * slot + 1] = baseIndex[3 * i + 1];
    index.array[3 * slot + 2] = baseIndex[3 * i + 2];
  }
  index.needsUpdate = true;
}

function setCamera(start) {
  var F = new THREE.Matrix4().makeScale(1, -1, -1);
  var c2w = new THREE.Matrix4();
  if (start) {
    c2w.set.apply(c2w, start.c2w);  // row-major, as Matrix4.set takes it
    intrinsics = start.intrinsics;
    viewAspect = start.aspect || null;
    fitCanvas();
  } else {  // frame the scene: in our world, look down +z at its centre
    var centre = bounds.center.clone().applyMatrix4(F);
    c2w.makeTranslation(centre.x, centre.y, centre.z - 2.5 * bounds.radius);
    intrinsics = [window.innerHeight / window.innerWidth, 1, 0.5, 0.5];
  }
  var world = new THREE.Matrix4().multiplyMatrices(F, c2w).multiply(F);
  world.decompose(camera.position, camera.quaternion, camera.scale);
  // Orbit about the camera's own up axis at the scene's depth in front of it,
  // so that the controls' lookAt keeps the start view exactly (roll included).
  var e = world.elements;
  camera.up.set(e[4], e[5], e[6]).normalize();
  var forward = new THREE.Vector3(-e[8], -e[9], -e[10]).normalize();
  var depth = bounds.center.clone().sub(camera.position).dot(forward);
  var target = camera.position.clone().addScaledVector(forward, Math.max(depth, 0.1 * bounds.radius, 10 * NEAR));
  controls = new THREE.OrbitControls(camera, renderer.domElement);
  controls.screenSpacePanning = true;
  controls.target.copy(target);
  controls.update();
  controls.addEventListener("change", requestDraw);
  controls.addEventListener("end", function () { sortTriangles(); requestDraw(); });
}

// A loaded GLB: its root, its one mesh, and the centroids the sort needs.
function prepare(gltf) {
  var node = null;
  gltf.scene.traverse(function (n) { if (n.isMesh && !node) node = n; });
  if (!node || !node.geometry.index || !node.geometry.attributes.color)
    throw new Error("the GLB has no indexed mesh with COLOR_0 (not written by FLAT-C++?)");
  gltf.scene.updateMatrixWorld(true);
  var geometry = node.geometry, position = geometry.attributes.position.array;
  geometry.setAttribute("rgba", geometry.attributes.color);  // VEC3 colours read alpha 1
  node.material = material;
  node.frustumCulled = false;
  var base = geometry.index.array.slice(), c = new Float32Array(base.length);
  for (var t = 0; t < base.length; ++t) {
    var corner = 3 * base[t], out = 3 * Math.floor(t / 3);
    for (var d = 0; d < 3; ++d) c[out + d] += position[corner + d] / 3;
  }
  return {root: gltf.scene, node: node, centroids: c, baseIndex: base};
}

var models = {}, shown = null;
function show(name) {
  if (shown) scene.remove(models[shown].root);
  shown = name;
  var m = models[name];
  scene.add(m.root);
  scene.updateMatrixWorld(true);
  mesh = m.node;
  centroids = m.centroids;
  baseIndex = m.baseIndex;
  sortTriangles();
  requestDraw();
  var button = document.getElementById("toggle");
  if (button) button.textContent = name === "mesh" ? "showing: opaque mesh (M: soup)" : "showing: triangle soup (M: mesh)";
  document.title = "FLAT viewer: " + (name === "mesh" ? "opaque mesh, " : "") + baseIndex.length / 3 + " triangles";
}

function toggle() { if (models.mesh) show(shown === "mesh" ? "soup" : "mesh"); }

function onLoad(soup, meshModel) {
  models.soup = soup;
  if (meshModel) {
    models.mesh = meshModel;
    var button = document.createElement("button");
    button.id = "toggle";
    button.addEventListener("click", toggle);
    document.body.appendChild(button);
    window.addEventListener("keydown", function (e) { if (e.key === "m" || e.key === "M") toggle(); });
  }
  new THREE.Box3().setFromObject(soup.root).getBoundingSphere(bounds);
  setCamera(startCamera());
  if (params.get("show") === "mesh" && !meshModel) throw new Error("show=mesh: this viewer has no opaque mesh");
  show(params.get("show") === "mesh" ? "mesh" : "soup");
  draw();
}

function parseGlb(base64, then) {
  new THREE.GLTFLoader().parse(decodeBase64(base64), "", function (gltf) {
    try { then(prepare(gltf)); } catch (e) { showError(e.message); }
  }, function (e) { showError("cannot read the GLB: " + (e.message || e)); });
}

window.addEventListener("resize", function () {
  fitCanvas();
  requestDraw();
});

try {
  if (!window.FLAT_SCENE_GLB) throw new Error("scene_glb.js is missing or empty");
  parseGlb(window.FLAT_SCENE_GLB, function (soup) {
    if (!window.FLAT_MESH_GLB) return onLoad(soup, null);
    parseGlb(window.FLAT_MESH_GLB, function (meshModel) { onLoad(soup, meshModel); });
  });
} catch (e) {
  showError(e.message);
}
</script>
</body>
</html>
)FLATPAGE";
}

}  // namespace flat::exporter
