// twinmill report viewer: the page's embedded GLB in three.js with orbit, zoom, pan, pick,
// layer switches and collision markers. Embedded in report.html by src/report/html.rs,
// which rewrites the imports below to the embedded three.js modules.
//
// Meshes by name: "part" (vertex colours = deviation, attribute _DEVIATION_UM), "cloud"
// (points, vertex colours = residual, attribute _RESIDUAL_UM), "plane ..." (line loops of
// the fitted planes). Sets window.twinmillReady once the first frame is drawn; offers
// window.twinmill.project([x, y, z]) -> [x, y] (page pixels) and .show(name, on) for tests.
import * as THREE from 'three';
import { OrbitControls } from 'three/addons/controls/OrbitControls.js';
import { GLTFLoader } from 'three/addons/loaders/GLTFLoader.js';

const meta = JSON.parse(document.getElementById('twinmill-view').textContent);
const box = document.getElementById('view');
const status = document.getElementById('view-status');
const pickBox = document.getElementById('pick');
const layersBox = document.getElementById('layers');

const b64 = document.getElementById('twinmill-glb').textContent.trim();
const raw = atob(b64);
const bytes = new Uint8Array(raw.length);
for (let i = 0; i < raw.length; i++) bytes[i] = raw.charCodeAt(i);

const renderer = new THREE.WebGLRenderer({ antialias: true });
renderer.setPixelRatio(window.devicePixelRatio || 1);
renderer.setSize(box.clientWidth, box.clientHeight);
box.insertBefore(renderer.domElement, box.firstChild);

const scene = new THREE.Scene();
scene.background = new THREE.Color(0xffffff);
const camera = new THREE.PerspectiveCamera(30, box.clientWidth / box.clientHeight, 0.01, 1e5);
camera.up.set(meta.up[0], meta.up[1], meta.up[2]);
scene.add(camera);
scene.add(new THREE.AmbientLight(0xffffff, 1.5));
const headlight = new THREE.DirectionalLight(0xffffff, 1.6);
headlight.position.set(-0.3, 0.5, 1);
camera.add(headlight);

const controls = new OrbitControls(camera, renderer.domElement);
const layers = new Map(); // name -> [objects]
const markers = [];
let ready = false;

function render() {
  renderer.render(scene, camera);
  for (const m of markers) {
    const v = m.position.clone().project(camera);
    const visible = m.object.visible && v.z < 1;
    m.label.style.display = visible ? '' : 'none';
    m.label.style.left = ((v.x + 1) / 2 * box.clientWidth + 6) + 'px';
    m.label.style.top = ((1 - v.y) / 2 * box.clientHeight - 8) + 'px';
  }
}
controls.addEventListener('change', render);

function layerName(name) {
  if (name.startsWith('plane')) return 'planes';
  if (name.startsWith('cloud')) return 'cloud';
  return name;
}

function addToLayer(name, obj) {
  const key = layerName(name);
  if (!layers.has(key)) layers.set(key, []);
  layers.get(key).push(obj);
}

function show(name, on) {
  for (const o of layers.get(name) || []) o.visible = on;
  const box = document.getElementById('layer-' + name);
  if (box) box.checked = on;
  render();
}

function buildLayerSwitches() {
  for (const [name, objs] of layers) {
    const label = document.createElement('label');
    const input = document.createElement('input');
    input.type = 'checkbox';
    input.id = 'layer-' + name;
    input.checked = objs.some(o => o.visible);
    input.addEventListener('change', () => show(name, input.checked));
    label.append(input, ' ' + name);
    layersBox.append(label, document.createElement('br'));
  }
}

function initiallyShown(name) {
  const key = layerName(name);
  return meta.shown.some(s => key === s);
}

function fmt(x, d) { return Number(x).toFixed(d); }

function onLoad(gltf) {
  const root = gltf.scene;
  let triangles = 0, points = 0;
  root.traverse(o => {
    if (!o.geometry) return;
    const name = (o.parent && o.parent.name && o.parent !== root ? o.parent.name : o.name) || '';
    const g = o.geometry;
    const coloured = g.attributes.color !== undefined;
    if (o.isPoints) {
      o.material = new THREE.PointsMaterial({ size: 2, sizeAttenuation: false, vertexColors: coloured });
      points += g.attributes.position.count;
    } else if (o.isLine || o.isLineSegments) {
      o.material = new THREE.LineBasicMaterial({ color: 0x1b7837 });
    } else if (o.isMesh) {
      o.material = new THREE.MeshLambertMaterial({
        vertexColors: coloured, color: coloured ? 0xffffff : 0xc8c8c8, flatShading: true,
      });
      triangles += g.index ? g.index.count / 3 : g.attributes.position.count / 3;
    }
    o.userData.layer = layerName(name);
    o.visible = initiallyShown(name);
    addToLayer(name, o);
  });
  scene.add(root);

  const bbox = new THREE.Box3().setFromObject(root);
  const size = bbox.getSize(new THREE.Vector3()).length() || 1;
  for (const m of meta.markers) {
    const p = new THREE.Vector3(m.position[0], m.position[1], m.position[2]);
    const s = new THREE.Mesh(
      new THREE.SphereGeometry(size * 0.01, 16, 12),
      new THREE.MeshBasicMaterial({ color: 0xb2182b }),
    );
    s.position.copy(p);
    s.userData.label = m.label;
    scene.add(s);
    addToLayer('collisions', s);
    const label = document.createElement('div');
    label.className = 'marker';
    label.textContent = m.label;
    box.append(label);
    markers.push({ position: p, label, object: s });
  }
  buildLayerSwitches();

  // Frame what is shown, from the scene's direction.
  const shownBox = new THREE.Box3();
  for (const objs of layers.values()) for (const o of objs) if (o.visible) shownBox.expandByObject(o);
  const frame = shownBox.isEmpty() ? bbox : shownBox;
  const centre = frame.getCenter(new THREE.Vector3());
  const radius = frame.getSize(new THREE.Vector3()).length() / 2 || 1;
  const eye = new THREE.Vector3(meta.eye[0], meta.eye[1], meta.eye[2]).normalize();
  const dist = radius / Math.sin(THREE.MathUtils.degToRad(camera.fov / 2)) * 1.05;
  camera.position.copy(centre).addScaledVector(eye, dist);
  camera.near = dist / 100;
  camera.far = dist * 100;
  camera.updateProjectionMatrix();
  controls.target.copy(centre);
  controls.update();
  status.remove();
  render();
  requestAnimationFrame(() => {
    ready = true;
    window.twinmillReady = { ms: performance.now(), triangles, points, markers: markers.length };
  });
}

// Pick: a click (not a drag) reports the nearest visible thing under the pointer.
const raycaster = new THREE.Raycaster();
let down = null;
renderer.domElement.addEventListener('pointerdown', e => { down = [e.clientX, e.clientY]; });
renderer.domElement.addEventListener('pointerup', e => {
  if (!down || Math.hypot(e.clientX - down[0], e.clientY - down[1]) > 4) return;
  const r = renderer.domElement.getBoundingClientRect();
  const ndc = new THREE.Vector2((e.clientX - r.left) / r.width * 2 - 1, 1 - (e.clientY - r.top) / r.height * 2);
  raycaster.setFromCamera(ndc, camera);
  raycaster.params.Points.threshold = camera.position.distanceTo(controls.target) * 0.004;
  const visible = [];
  scene.traverse(o => { if (o.geometry && o.visible && (!o.parent || o.parent.visible !== false)) visible.push(o); });
  const hit = raycaster.intersectObjects(visible, false)[0];
  if (!hit) { pickBox.textContent = ''; return; }
  const p = hit.point;
  let text = (hit.object.userData.layer || hit.object.name || 'object') +
    ' at (' + fmt(p.x, 3) + ', ' + fmt(p.y, 3) + ', ' + fmt(p.z, 3) + ') mm';
  const g = hit.object.geometry;
  if (hit.object.userData.label) text += ': ' + hit.object.userData.label;
  if (hit.face && g.attributes._deviation_um) {
    const a = g.attributes._deviation_um;
    const tri = new THREE.Triangle(
      new THREE.Vector3().fromBufferAttribute(g.attributes.position, hit.face.a),
      new THREE.Vector3().fromBufferAttribute(g.attributes.position, hit.face.b),
      new THREE.Vector3().fromBufferAttribute(g.attributes.position, hit.face.c));
    const w = tri.getBarycoord(hit.object.worldToLocal(p.clone()), new THREE.Vector3());
    const d = w.x * a.getX(hit.face.a) + w.y * a.getX(hit.face.b) + w.z * a.getX(hit.face.c);
    text += ', deviation ' + fmt(d, 2) + ' µm';
  } else if (hit.index !== undefined && g.attributes._residual_um) {
    text += ', residual ' + fmt(g.attributes._residual_um.getX(hit.index), 2) + ' µm';
  }
  pickBox.textContent = text;
});

new ResizeObserver(() => {
  const w = box.clientWidth, h = box.clientHeight;
  if (!w || !h) return;
  renderer.setSize(w, h);
  camera.aspect = w / h;
  camera.updateProjectionMatrix();
  render();
}).observe(box);

window.twinmill = {
  project(xyz) {
    const v = new THREE.Vector3(xyz[0], xyz[1], xyz[2]).project(camera);
    const r = renderer.domElement.getBoundingClientRect();
    return [r.left + (v.x + 1) / 2 * r.width, r.top + (1 - v.y) / 2 * r.height];
  },
  canvas() {
    const r = renderer.domElement.getBoundingClientRect();
    return [r.left, r.top, r.width, r.height];
  },
  layers() { return [...layers.keys()]; },
  show,
  isReady() { return ready; },
};

new GLTFLoader().parse(bytes.buffer, '', onLoad, e => {
  window.twinmillError = String(e);
  status.textContent = 'The 3-D view could not read its geometry: ' + e;
  console.error(e);
});
