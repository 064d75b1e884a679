/*
 * The console's 3D view: the robot from its URDF, the object, the tables, the support polygon with
 * the threshold band, and the CoM and ZMP on the floor, posed at one trajectory index at a time.
 *
 * three.js and urdf-loader come from the package's vendored copies (import map in index.html), so
 * nothing is fetched from the internet. The world is the contract's frame: z up, x forward.
 * app.js drives it through window.regrasp3d (show, setIndex, setMeasured, ...) and hears picks in
 * the view as "regrasp:pick" events with the picked trajectory index.
 *
 * The robot's CoM is recomputed here from the URDF's inertials at the drawn pose (comAt), so an
 * executed pose reported by the controller gets a margin computed from the measured joints, not
 * the plan's numbers.
 */
import * as THREE from "three";
import { OrbitControls } from "three/addons/controls/OrbitControls.js";
import { OBJLoader } from "three/addons/loaders/OBJLoader.js";
import { STLLoader } from "three/addons/loaders/STLLoader.js";
import { ColladaLoader } from "three/addons/loaders/ColladaLoader.js";
import URDFLoader from "urdf-loader";

const COLORS = {
  background: 0xf3f5f8, robot: 0x8a97a8, robotExec: 0xd9822b, object: 0xe0a030, table: 0xa07850,
  obstacle: 0xb05050, support: 0x1a8f4a, band: 0xe07b00, com: 0x2457d6, zmp: 0x8e3fb5, worst: 0xc62828,
  exec: 0xd9822b, compare: 0x777777,
};
const FLOOR_Z = 0.002;
/** Shortest time between two frames, ms (software WebGL in a headless browser takes tens of ms per frame). */
const MIN_FRAME_MS = 50;

class View3D {
  constructor(container) {
    this.container = container;
    this.plan = null;
    this.robot = null;
    this.index = 0;
    this.inertials = [];
    this.objectMass = 0;
    this.objectCom = new THREE.Vector3();
    try {
      this.renderer = new THREE.WebGLRenderer({ antialias: true, preserveDrawingBuffer: true });
    } catch (err) {
      this.renderer = null;
      container.textContent = "3D view unavailable: this browser has no WebGL (" + err.message + ")";
      return;
    }
    this.renderer.setPixelRatio(1);
    this.renderer.setClearColor(COLORS.background, 1);
    container.replaceChildren(this.renderer.domElement);
    this.renderer.domElement.setAttribute("data-role", "view3d-canvas");
    this.scene = new THREE.Scene();
    this.camera = new THREE.PerspectiveCamera(40, 1, 0.02, 50);
    this.camera.up.set(0, 0, 1);
    this.camera.position.set(-0.5, -3.6, 1.6);  // replaced by frame() once a plan is drawn
    this.controls = new OrbitControls(this.camera, this.renderer.domElement);
    this.controls.target.set(0.25, 0, 0.8);
    this.controls.addEventListener("change", () => this.render());
    this.scene.add(new THREE.HemisphereLight(0xffffff, 0x667080, 2.2));
    const sun = new THREE.DirectionalLight(0xffffff, 1.6);
    sun.position.set(2, -3, 5);
    this.scene.add(sun);
    const grid = new THREE.GridHelper(4, 40, 0xc5ccd6, 0xdde2e8);
    grid.rotation.x = Math.PI / 2;  // the helper lies in xz; the floor here is xy
    this.scene.add(grid);
    this.world = new THREE.Group();
    this.scene.add(this.world);
    this.markers = new THREE.Group();
    this.scene.add(this.markers);
    this.resize();
    new ResizeObserver(() => this.resize()).observe(container);
    this.renderer.domElement.addEventListener("click", (e) => this.pick(e));
  }

  resize() {
    if (!this.renderer) return;
    const w = Math.max(this.container.clientWidth, 200), h = Math.max(this.container.clientHeight, 200);
    this.renderer.setSize(w, h, false);
    this.renderer.domElement.style.width = "100%";
    this.renderer.domElement.style.height = "100%";
    this.camera.aspect = w / h;
    this.camera.updateProjectionMatrix();
    this.render();
  }

  /* Draw soon: at most one frame per MIN_FRAME_MS, so a stream of execution events cannot hog the page. */
  render() {
    if (!this.renderer || this.pending) return;
    this.pending = true;
    const wait = Math.max(0, MIN_FRAME_MS - (performance.now() - (this.lastFrame || 0)));
    setTimeout(() => requestAnimationFrame(() => this.renderNow()), wait);
  }

  renderNow() {
    this.pending = false;
    if (!this.renderer) return;
    this.lastFrame = performance.now();
    this.renderer.render(this.scene, this.camera);
  }

  clear() {
    for (const g of [this.world, this.markers]) {
      for (const child of [...g.children]) { g.remove(child); disposeTree(child); }
    }
    this.robot = null;
    this.ghost = null;
    this.compareLine = null;
    this.plan = null;
  }

  /* Draw a plan: the robot (URDF text), scene boxes, floor traces; then pose it at index 0. */
  async show(plan, urdfText, fetchMesh) {
    if (!this.renderer) return;
    this.clear();
    this.plan = plan;
    this.urdfText = urdfText;
    this.fetchMesh = fetchMesh;
    this.inertials = parseInertials(urdfText);
    const material = new THREE.MeshStandardMaterial({ color: COLORS.robot, roughness: 0.7, metalness: 0.1 });
    const loader = new URDFLoader();
    loader.loadMeshCb = (path, manager, _urdfMaterial, done) => loadMesh(path, manager, material, done, fetchMesh);
    loader.parseCollision = false;
    const robot = loader.parse(urdfText);
    robot.traverse((o) => { if (o.isMesh) o.material = material; });
    this.robotMaterial = material;
    const base = (plan.stance && plan.stance.base_pose) || [0, 0, 0, 0, 0, 0, 1];
    robot.position.set(base[0], base[1], base[2]);
    robot.quaternion.set(base[3], base[4], base[5], base[6]);
    this.robot = robot;
    this.world.add(robot);
    this.addScene(plan);
    this.addFloor(plan);
    this.setIndex(0);
    if (!(plan.trajectory || []).length) this.poseAsPlanned(plan);
    this.frame();
  }

  /* A plan without motion (a failed one): the robot in its stance's posture, the object where the task puts it. */
  poseAsPlanned(plan) {
    const stance = plan.stance || {};
    if (Array.isArray(stance.q) && plan.robot && Array.isArray(plan.robot.joint_names)) this.applyJoints(plan.robot.joint_names, stance.q);
    const obj = plan.object || {};
    const pose = obj.start_pose || obj.pose;
    if (Array.isArray(pose) && pose.length === 7) setPose(this.object, pose);
    else this.object.visible = false;  // nowhere known: not drawn rather than drawn at the origin
    this.render();
  }

  /* The measured pose as a translucent ghost beside the plan's robot (after a stop: where the robot really is). */
  showGhost(names, q) {
    if (!this.renderer || !this.plan || !this.urdfText) return false;
    if (!this.ghost) {
      const material = new THREE.MeshStandardMaterial({ color: COLORS.robotExec, transparent: true, opacity: 0.45, depthWrite: false });
      const loader = new URDFLoader();
      loader.loadMeshCb = (path, manager, _m, done) => loadMesh(path, manager, material, done, this.fetchMesh);
      loader.parseCollision = false;
      const ghost = loader.parse(this.urdfText);
      ghost.traverse((o) => { if (o.isMesh) o.material = material; });
      const base = (this.plan.stance && this.plan.stance.base_pose) || [0, 0, 0, 0, 0, 0, 1];
      ghost.position.set(base[0], base[1], base[2]);
      ghost.quaternion.set(base[3], base[4], base[5], base[6]);
      ghost.userData.role = "measured-ghost";
      this.ghost = ghost;
      this.world.add(ghost);
    }
    const values = {};
    names.forEach((n, k) => { if (this.ghost.joints[n]) values[n] = q[k]; });
    this.ghost.setJointValues(values);
    this.ghost.updateMatrixWorld(true);
    this.ghost.visible = true;
    this.render();
    return true;
  }

  ghostShown() { return !!(this.ghost && this.ghost.visible); }

  /* A comparison plan's CoM ground trace (grey), beside this plan's. */
  showComparison(trajectory) {
    if (this.compareLine) { this.world.remove(this.compareLine); disposeTree(this.compareLine); this.compareLine = null; }
    const com = (trajectory || []).filter((p) => Array.isArray(p.com)).map((p) => [p.com[0], p.com[1]]);
    if (com.length > 1) {
      this.compareLine = polyline(com, COLORS.compare, FLOOR_Z * 3.5);
      this.compareLine.userData.role = "comparison";
      this.world.add(this.compareLine);
    }
    this.render();
  }

  /* Point the camera at everything drawn, from the robot's right and a little ahead and above. */
  frame() {
    const box = new THREE.Box3().setFromObject(this.world);
    if (box.isEmpty()) return;
    const centre = box.getCenter(new THREE.Vector3());
    const size = box.getSize(new THREE.Vector3());
    const fov = THREE.MathUtils.degToRad(this.camera.fov);
    const fit = Math.max(size.z, size.x / this.camera.aspect, size.y / this.camera.aspect);
    const distance = 1.15 * fit / (2 * Math.tan(fov / 2)) + Math.max(size.x, size.y) / 2;
    const dir = new THREE.Vector3(-0.15, -1, 0.35).normalize();  // tables ahead of the robot stay beside it
    this.controls.target.copy(centre);
    this.camera.position.copy(centre).addScaledVector(dir, distance);
    this.controls.update();
    this.render();
  }

  addScene(plan) {
    const sc = plan.scenario || {};
    for (const [list, color, role] of [[sc.tables || [], COLORS.table, "table"], [sc.obstacles || [], COLORS.obstacle, "obstacle"]]) {
      for (const box of list) {
        if (!Array.isArray(box.size) || !Array.isArray(box.pose)) continue;
        const mesh = new THREE.Mesh(new THREE.BoxGeometry(...box.size),
          new THREE.MeshStandardMaterial({ color, roughness: 0.9, transparent: true, opacity: role === "obstacle" ? 0.6 : 0.8 }));
        setPose(mesh, box.pose);
        mesh.userData.role = role;
        this.world.add(mesh);
      }
    }
    const obj = plan.object || {};
    this.objectMass = Number(obj.mass_kg || 0);
    this.objectCom.fromArray(obj.com_local || [0, 0, 0]);
    this.object = new THREE.Group();
    this.object.userData.role = "object";
    this.object.add(objectGeometry(sc.object || {}, (mesh) => { this.object.add(mesh); this.render(); }));
    const dot = new THREE.Mesh(new THREE.SphereGeometry(0.012), new THREE.MeshBasicMaterial({ color: 0x333333 }));
    dot.position.copy(this.objectCom);
    this.object.add(dot);
    this.world.add(this.object);
  }

  addFloor(plan) {
    const poly = plan.support_polygon || [];
    const thr = Number(plan.threshold_m || 0);
    if (poly.length >= 3) {
      const outer = new THREE.Shape(poly.map(([x, y]) => new THREE.Vector2(x, y)));
      const inner = shrinkConvex(poly, thr);
      if (inner.length >= 3) {
        const band = outer.clone();
        band.holes.push(new THREE.Path(inner.map(([x, y]) => new THREE.Vector2(x, y)).reverse()));
        this.world.add(flat(new THREE.Mesh(new THREE.ShapeGeometry(band),
          new THREE.MeshBasicMaterial({ color: COLORS.band, transparent: true, opacity: 0.35, side: THREE.DoubleSide })), FLOOR_Z));
        this.world.add(flat(new THREE.Mesh(new THREE.ShapeGeometry(new THREE.Shape(inner.map(([x, y]) => new THREE.Vector2(x, y)))),
          new THREE.MeshBasicMaterial({ color: COLORS.support, transparent: true, opacity: 0.18, side: THREE.DoubleSide })), FLOOR_Z));
      }
      this.world.add(loop(poly, COLORS.support, FLOOR_Z * 2));
    }
    const traj = plan.trajectory || [];
    const com = traj.filter((p) => Array.isArray(p.com)).map((p) => [p.com[0], p.com[1]]);
    const zmp = traj.filter((p) => Array.isArray(p.zmp)).map((p) => [p.zmp[0], p.zmp[1]]);
    if (com.length > 1) this.world.add(polyline(com, COLORS.com, FLOOR_Z * 3));
    if (zmp.length > 1) this.world.add(polyline(zmp, COLORS.zmp, FLOOR_Z * 2.5));
    // The worst margin point: a red ring on the floor.
    let worst = -1, best = Infinity;
    traj.forEach((p, i) => { if (typeof p.margin_m === "number" && p.margin_m < best) { best = p.margin_m; worst = i; } });
    if (worst >= 0 && Array.isArray(traj[worst].com)) {
      const ring = new THREE.Mesh(new THREE.RingGeometry(0.012, 0.02, 32), new THREE.MeshBasicMaterial({ color: COLORS.worst, side: THREE.DoubleSide }));
      ring.position.set(traj[worst].com[0], traj[worst].com[1], FLOOR_Z * 4);
      ring.userData.role = "worst";
      this.world.add(ring);
    }
    // Markers moved by setIndex: the CoM (sphere, its floor point, a plumb line), the ZMP, the executed CoM.
    const mk = (geo, color) => new THREE.Mesh(geo, new THREE.MeshBasicMaterial({ color, depthTest: false }));
    this.comBall = mk(new THREE.SphereGeometry(0.025), COLORS.com);
    this.comFloor = mk(new THREE.CircleGeometry(0.014, 24), COLORS.com);
    this.zmpFloor = mk(new THREE.CircleGeometry(0.011, 4), COLORS.zmp);
    this.execFloor = mk(new THREE.RingGeometry(0.016, 0.024, 24), COLORS.exec);
    this.execFloor.visible = false;
    this.plumb = new THREE.Line(new THREE.BufferGeometry().setFromPoints([new THREE.Vector3(), new THREE.Vector3()]),
      new THREE.LineDashedMaterial({ color: COLORS.com, dashSize: 0.03, gapSize: 0.02 }));
    for (const m of [this.comBall, this.comFloor, this.zmpFloor, this.execFloor, this.plumb]) { m.renderOrder = 10; this.markers.add(m); }
  }

  /* Pose everything at trajectory point i (the plan's joints and object pose). */
  setIndex(i) {
    const plan = this.plan;
    if (!plan || !this.robot) return;
    const traj = plan.trajectory || [];
    if (!traj.length) return;
    i = Math.max(0, Math.min(traj.length - 1, Math.round(i)));
    this.index = i;
    const p = traj[i];
    this.applyJoints(plan.robot.joint_names, p.q);
    if (Array.isArray(p.object_pose)) setPose(this.object, p.object_pose);
    if (Array.isArray(p.com)) {
      this.comBall.position.set(p.com[0], p.com[1], p.com[2]);
      this.comFloor.position.set(p.com[0], p.com[1], FLOOR_Z * 5);
      this.plumb.geometry.setFromPoints([new THREE.Vector3(p.com[0], p.com[1], p.com[2]), new THREE.Vector3(p.com[0], p.com[1], 0)]);
      this.plumb.computeLineDistances();
    }
    if (Array.isArray(p.zmp)) this.zmpFloor.position.set(p.zmp[0], p.zmp[1], FLOOR_Z * 5);
    this.robotMaterial.color.setHex(COLORS.robot);
    this.render();
  }

  applyJoints(names, q) {
    if (!Array.isArray(names) || !Array.isArray(q)) return;
    const values = {};
    names.forEach((n, k) => { if (this.robot.joints[n]) values[n] = q[k]; });
    this.robot.setJointValues(values);
    this.robot.updateMatrixWorld(true);
  }

  /* The robot at a measured joint state (the controller's report); its CoM and margin, computed here. */
  setMeasured(names, q, index) {
    if (!this.plan || !this.robot) return null;
    const traj = this.plan.trajectory || [];
    const i = Math.max(0, Math.min(traj.length - 1, index | 0));
    this.applyJoints(names, q);
    const p = traj[i] || {};
    if (Array.isArray(p.object_pose)) setPose(this.object, p.object_pose);
    const com = this.systemCom(p);
    const margin = marginOf(this.plan.support_polygon || [], com.x, com.y);
    this.execFloor.position.set(com.x, com.y, FLOOR_Z * 6);
    this.execFloor.visible = true;
    this.robotMaterial.color.setHex(COLORS.robotExec);
    this.render();
    return { com: [com.x, com.y, com.z], margin_m: margin };
  }

  /* Robot CoM from the URDF inertials at the drawn pose, plus the held object's (planned) CoM. */
  systemCom(point) {
    const sum = new THREE.Vector3();
    let mass = 0;
    const v = new THREE.Vector3();
    for (const { link, m, xyz } of this.inertials) {
      const obj = this.robot.links[link];
      if (!obj) continue;
      v.fromArray(xyz).applyMatrix4(obj.matrixWorld);
      sum.addScaledVector(v, m);
      mass += m;
    }
    if (point && point.holding && point.holding !== "none" && Array.isArray(point.object_pose) && this.objectMass > 0) {
      const pose = point.object_pose;
      v.copy(this.objectCom).applyQuaternion(new THREE.Quaternion(pose[3], pose[4], pose[5], pose[6]))
        .add(new THREE.Vector3(pose[0], pose[1], pose[2]));
      sum.addScaledVector(v, this.objectMass);
      mass += this.objectMass;
    }
    return mass > 0 ? sum.divideScalar(mass) : sum;
  }

  /* The system CoM recomputed from the URDF at plan point i (tests compare it with the plan's). */
  comAt(i) {
    this.setIndex(i);
    const c = this.systemCom((this.plan.trajectory || [])[this.index]);
    return [c.x, c.y, c.z];
  }

  clearMeasured() {
    if (this.execFloor) this.execFloor.visible = false;
    this.setIndex(this.index);
  }

  pick(event) {
    const traj = (this.plan && this.plan.trajectory) || [];
    if (!traj.length) return;
    const rect = this.renderer.domElement.getBoundingClientRect();
    const ndc = new THREE.Vector2(((event.clientX - rect.left) / rect.width) * 2 - 1, -((event.clientY - rect.top) / rect.height) * 2 + 1);
    const ray = new THREE.Raycaster();
    ray.setFromCamera(ndc, this.camera);
    const hit = new THREE.Vector3();
    if (!ray.ray.intersectPlane(new THREE.Plane(new THREE.Vector3(0, 0, 1), 0), hit)) return;
    let best = -1, bestD = 0.05;  // within 5 cm of the CoM trace on the floor
    traj.forEach((p, i) => {
      if (!Array.isArray(p.com)) return;
      const d = Math.hypot(p.com[0] - hit.x, p.com[1] - hit.y);
      if (d < bestD) { bestD = d; best = i; }
    });
    if (best >= 0) this.container.dispatchEvent(new CustomEvent("regrasp:pick", { detail: { index: best }, bubbles: true }));
  }

  setRobotVisible(visible) { if (this.robot) { this.robot.visible = visible; this.renderNow(); } }

  /* The world position of a link's origin (tests check that a pose moved the arm). */
  linkPosition(name) {
    const link = this.robot && this.robot.links[name];
    if (!link) return null;
    const v = new THREE.Vector3().setFromMatrixPosition(link.matrixWorld);
    return [v.x, v.y, v.z];
  }
}

// ------------------------------------------------------------------ helpers
function setPose(obj, pose) {
  obj.position.set(pose[0], pose[1], pose[2]);
  obj.quaternion.set(pose[3], pose[4], pose[5], pose[6]).normalize();
}

function flat(mesh, z) { mesh.position.z = z; return mesh; }

function polyline(points, color, z) {
  const geo = new THREE.BufferGeometry().setFromPoints(points.map(([x, y]) => new THREE.Vector3(x, y, z)));
  return new THREE.Line(geo, new THREE.LineBasicMaterial({ color }));
}

function loop(points, color, z) {
  const geo = new THREE.BufferGeometry().setFromPoints(points.map(([x, y]) => new THREE.Vector3(x, y, z)));
  return new THREE.LineLoop(geo, new THREE.LineBasicMaterial({ color }));
}

function disposeTree(obj) {
  obj.traverse((o) => {
    if (o.geometry) o.geometry.dispose();
    if (o.material) (Array.isArray(o.material) ? o.material : [o.material]).forEach((m) => m.dispose());
  });
}

/* The object's shape in its own frame (docs/contract.md section 2): box centred, bar from its base, cylinder along z. */
function objectGeometry(def, onMesh) {
  const material = new THREE.MeshStandardMaterial({ color: COLORS.object, roughness: 0.6 });
  const size = Array.isArray(def.size) ? def.size : null;
  if ((def.shape === "box" || def.shape === "drill") && size) return new THREE.Mesh(new THREE.BoxGeometry(...size), material);
  if (def.shape === "bar" && size) {
    const m = new THREE.Mesh(new THREE.BoxGeometry(...size), material);
    m.position.z = size[2] / 2;
    return m;
  }
  if (def.shape === "cylinder" && size) {
    const m = new THREE.Mesh(new THREE.CylinderGeometry(size[0], size[0], size[1], 32), material);
    m.rotation.x = Math.PI / 2;  // three's cylinder runs along y
    return m;
  }
  if (def.shape === "mesh" && def.mesh && def.mesh.name && window.regrasp3d.fetchObjectMesh) {
    window.regrasp3d.fetchObjectMesh(def.mesh.name).then((text) => {
      if (!text) return;
      const group = new OBJLoader().parse(text);
      const scale = Number(def.mesh.scale || 1);
      group.scale.set(scale, scale, scale);
      group.traverse((o) => { if (o.isMesh) o.material = material; });
      onMesh(group);
    }).catch(() => {});
  }
  // A drill without a size, or a mesh not (yet) loaded: a small marker box.
  return new THREE.Mesh(new THREE.BoxGeometry(0.06, 0.06, 0.06), material);
}

function parseInertials(urdfText) {
  const doc = new DOMParser().parseFromString(urdfText, "application/xml");
  const out = [];
  for (const link of doc.querySelectorAll("robot > link")) {
    const inertial = link.querySelector(":scope > inertial");
    if (!inertial) continue;
    const massNode = inertial.querySelector(":scope > mass");
    const m = massNode ? Number(massNode.getAttribute("value")) : 0;
    if (!(m > 0)) continue;
    const origin = inertial.querySelector(":scope > origin");
    const xyz = origin && origin.getAttribute("xyz") ? origin.getAttribute("xyz").trim().split(/\s+/).map(Number) : [0, 0, 0];
    out.push({ link: link.getAttribute("name"), m, xyz });
  }
  return out;
}

function loadMesh(path, manager, material, done, fetchMesh) {
  if (!path || !fetchMesh) { done(null); return; }
  fetchMesh(path).then((buffer) => {
    if (!buffer) { done(null); return; }
    if (/\.stl$/i.test(path)) done(new THREE.Mesh(new STLLoader(manager).parse(buffer), material));
    else if (/\.dae$/i.test(path)) {
      const scene = new ColladaLoader(manager).parse(new TextDecoder().decode(buffer), "").scene;
      scene.traverse((o) => { if (o.isMesh) o.material = material; });
      done(scene);
    }
    else done(null);
  }).catch((err) => done(null, err));
}

/* Signed distance of (x, y) to the edge of a convex polygon, inside positive (as margin_m). */
function marginOf(poly, x, y) {
  let area = 0;
  for (let i = 0; i < poly.length; i++) { const [x1, y1] = poly[i], [x2, y2] = poly[(i + 1) % poly.length]; area += x1 * y2 - x2 * y1; }
  const pts = area >= 0 ? poly : poly.slice().reverse();
  let best = Infinity;
  for (let i = 0; i < pts.length; i++) {
    const [x1, y1] = pts[i], [x2, y2] = pts[(i + 1) % pts.length];
    const len = Math.hypot(x2 - x1, y2 - y1);
    if (len < 1e-12) continue;
    best = Math.min(best, ((x2 - x1) * (y - y1) - (y2 - y1) * (x - x1)) / len);
  }
  return best;
}

function shrinkConvex(poly, d) {
  return window.regraspConsole && window.regraspConsole.shrinkConvex ? window.regraspConsole.shrinkConvex(poly, d) : [];
}

// ------------------------------------------------------------------ wiring
let view = null;
window.regrasp3d = {
  ready: true,
  fetchObjectMesh: null,
  ensure(container) { if (!view) view = new View3D(container); return view; },
  show(plan, urdfText, fetchMesh) { return view ? view.show(plan, urdfText, fetchMesh) : Promise.resolve(); },
  setIndex(i) { if (view) view.setIndex(i); },
  setMeasured(names, q, index) { return view ? view.setMeasured(names, q, index) : null; },
  showGhost(names, q) { return view ? view.showGhost(names, q) : false; },
  ghostShown() { return view ? view.ghostShown() : false; },
  showComparison(trajectory) { if (view) view.showComparison(trajectory); },
  comparisonShown() { return !!(view && view.compareLine && view.compareLine.parent); },
  clearMeasured() { if (view) view.clearMeasured(); },
  clear() { if (view) { view.clear(); view.render(); } },
  comAt(i) { return view ? view.comAt(i) : null; },
  index() { return view ? view.index : null; },
  linkPosition(name) { return view ? view.linkPosition(name) : null; },
  setRobotVisible(v) { if (view) view.setRobotVisible(v); },
  hasWebGL() { return !!(view && view.renderer); },
  marginOf,
};
window.dispatchEvent(new Event("regrasp3d:ready"));
