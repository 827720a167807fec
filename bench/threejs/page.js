// three.js's shadowed frame of a scene the Python side describes (bench/vs_threejs.py): the
// same triangles, instance matrices, materials, camera and lights as our render, with three's
// own PCF shadow maps (PCFShadowMap, 2048 texels, the shadow camera fitted to the scene).
import * as THREE from "three";

const MAP_SIZE = 2048;

function floats(b64) {
  const bytes = Uint8Array.from(atob(b64), (c) => c.charCodeAt(0));
  return new Float32Array(bytes.buffer);
}

function uints(b64) {
  const bytes = Uint8Array.from(atob(b64), (c) => c.charCodeAt(0));
  return new Uint32Array(bytes.buffer);
}

async function texture(b64) {
  const blob = await (await fetch(`data:image/png;base64,${b64}`)).blob();
  const bitmap = await createImageBitmap(blob, { imageOrientation: "flipY",
    premultiplyAlpha: "none", colorSpaceConversion: "none" });
  const tex = new THREE.Texture(bitmap);
  tex.flipY = false;  // glTF's texture coordinates: origin at the image's top left
  tex.colorSpace = THREE.SRGBColorSpace;
  tex.wrapS = tex.wrapT = THREE.RepeatWrapping;
  tex.needsUpdate = true;
  return tex;
}

let state = null;

// The near and far distances of the scene's bounding box along a camera's view axis.
function fitDepth(cam, lo, hi) {
  cam.updateMatrixWorld(true);
  const inv = cam.matrixWorldInverse;
  let zmin = Infinity, zmax = -Infinity, xmin = Infinity, xmax = -Infinity;
  let ymin = Infinity, ymax = -Infinity;
  for (let k = 0; k < 8; ++k) {
    const v = new THREE.Vector3(k & 1 ? hi[0] : lo[0], k & 2 ? hi[1] : lo[1],
                                k & 4 ? hi[2] : lo[2]).applyMatrix4(inv);
    zmin = Math.min(zmin, -v.z); zmax = Math.max(zmax, -v.z);
    xmin = Math.min(xmin, v.x); xmax = Math.max(xmax, v.x);
    ymin = Math.min(ymin, v.y); ymax = Math.max(ymax, v.y);
  }
  return { zmin, zmax, xmin, xmax, ymin, ymax };
}

async function load(desc) {
  if (state) dispose();
  const renderer = new THREE.WebGLRenderer({ antialias: false, alpha: false });
  renderer.setPixelRatio(1);
  renderer.setSize(desc.camera.width, desc.camera.height);
  renderer.setClearColor(0xffffff, 1);
  renderer.shadowMap.enabled = true;
  renderer.shadowMap.type = THREE.PCFShadowMap;
  // The canvas stays out of the document: no compositing of it runs beside the timed frames
  // (or beside ours, in the interleaved runs).
  const scene = new THREE.Scene();
  // three's Lambert term carries 1/pi (physically based lights since r155): intensities times pi
  // give ours's brightness.
  scene.add(new THREE.AmbientLight(0xffffff, desc.ambient * Math.PI));
  const materials = [], geometries = [];
  for (const p of desc.primitives) {
    const g = new THREE.BufferGeometry();
    g.setAttribute("position", new THREE.BufferAttribute(floats(p.positions), 3));
    g.setAttribute("normal", new THREE.BufferAttribute(floats(p.normals), 3));
    if (p.uv) g.setAttribute("uv", new THREE.BufferAttribute(floats(p.uv), 2));
    if (p.colors) g.setAttribute("color", new THREE.BufferAttribute(floats(p.colors), 4));
    g.setIndex(new THREE.BufferAttribute(uints(p.indices), 1));
    const m = p.material;
    const mat = new THREE.MeshPhongMaterial({
      color: new THREE.Color().setRGB(m.base_color[0], m.base_color[1], m.base_color[2],
                                      THREE.LinearSRGBColorSpace),
      opacity: m.base_color[3],
      transparent: m.alpha_mode === "BLEND",
      alphaTest: m.alpha_mode === "MASK" ? m.alpha_cutoff : 0,
      side: m.double_sided ? THREE.DoubleSide : THREE.FrontSide,
      // Every triangle casts, as in ours and the reference (three's default draws only the back
      // faces of one-sided materials into the map: a one-sided plane facing the light would
      // cast nothing).
      shadowSide: THREE.DoubleSide,
      vertexColors: !!p.colors,
      shininess: 32,
      specular: 0x222222,
    });
    if (m.texture && p.uv) mat.map = await texture(m.texture);
    materials.push(mat);
    geometries.push(g);
  }
  for (const inst of desc.instances) {
    const mesh = new THREE.Mesh(geometries[inst.primitive], materials[inst.primitive]);
    mesh.matrixAutoUpdate = false;
    mesh.matrix.fromArray(inst.matrix);
    mesh.castShadow = inst.cast_shadow;
    mesh.receiveShadow = inst.receive_shadow;
    scene.add(mesh);
  }
  const c = desc.camera;
  const camera = new THREE.PerspectiveCamera(c.yfov * 180 / Math.PI, c.width / c.height,
                                             c.znear, c.zfar);
  camera.matrixAutoUpdate = false;
  camera.matrix.fromArray(c.pose);
  camera.matrixWorldNeedsUpdate = true;
  const lo = desc.bounds[0], hi = desc.bounds[1];
  const centre = new THREE.Vector3((lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, (lo[2] + hi[2]) / 2);
  const radius = new THREE.Vector3(hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]).length() / 2;
  const lights = [];
  for (const lt of desc.lights) {
    const color = new THREE.Color().setRGB(lt.color[0], lt.color[1], lt.color[2],
                                           THREE.LinearSRGBColorSpace);
    let light;
    if (lt.type === "directional") {
      light = new THREE.DirectionalLight(color, lt.intensity * Math.PI);
      const d = new THREE.Vector3(...lt.direction).normalize();
      light.position.copy(centre).addScaledVector(d, -2 * radius);
      light.target.position.copy(centre);
      scene.add(light.target);
      // The orthographic shadow camera fitted to the scene's box in light space.
      const cam = light.shadow.camera;
      cam.position.copy(light.position);
      cam.lookAt(centre);
      const f = fitDepth(cam, lo, hi);
      cam.left = f.xmin; cam.right = f.xmax; cam.bottom = f.ymin; cam.top = f.ymax;
      cam.near = Math.max(f.zmin, 1e-6); cam.far = f.zmax;
    } else {
      const pos = new THREE.Vector3(...lt.position);
      if (lt.type === "spot") {
        light = new THREE.SpotLight(color, lt.intensity * Math.PI, lt.range || 0, lt.outer_cone,
                                    1 - lt.inner_cone / Math.max(lt.outer_cone, 1e-6), 0);
        light.target.position.copy(pos).add(new THREE.Vector3(...lt.direction));
        scene.add(light.target);
      } else {
        light = new THREE.PointLight(color, lt.intensity * Math.PI, lt.range || 0, 0);
      }
      light.position.copy(pos);
      const cam = light.shadow.camera;
      const dmax = pos.distanceTo(centre) + radius;
      cam.near = Math.max(dmax * 1e-3, pos.distanceTo(centre) - radius);
      cam.far = dmax;
    }
    light.castShadow = lt.cast_shadows;
    light.shadow.mapSize.set(MAP_SIZE, MAP_SIZE);
    // A texel's world size at the scene's centre: the normal offset three's docs suggest.
    light.shadow.normalBias = desc.texel_world[lights.length];
    light.shadow.bias = -1e-4;
    light.shadow.camera.updateProjectionMatrix();
    scene.add(light);
    lights.push({ light, intensity: light.intensity, cast: lt.cast_shadows });
  }
  const gl = renderer.getContext();
  const pixels = new Uint8Array(c.width * c.height * 4);
  state = { renderer, scene, camera, lights, gl, pixels, materials, geometries,
            width: c.width, height: c.height };
  frame();
  const info = gl.getExtension("WEBGL_debug_renderer_info");
  return { renderer: info ? gl.getParameter(info.UNMASKED_RENDERER_WEBGL) : gl.getParameter(gl.RENDERER),
           revision: THREE.REVISION };
}

// One frame: shadow maps, camera pass and the read-back of every pixel (which waits for both),
// or with `whole` false of one pixel only (the wait without the copy).
function frame(whole = true) {
  const s = state;
  s.renderer.render(s.scene, s.camera);
  if (whole) s.gl.readPixels(0, 0, s.width, s.height, s.gl.RGBA, s.gl.UNSIGNED_BYTE, s.pixels);
  else s.gl.readPixels(0, 0, 1, 1, s.gl.RGBA, s.gl.UNSIGNED_BYTE, s.pixels);
}

function setShadows(on) {
  for (const l of state.lights) l.light.castShadow = on && l.cast;
}

function time(n, shadows, whole) {
  setShadows(shadows);
  frame(whole);  // a changed variant compiles its programs here, not in the timed frames
  const out = [];
  for (let k = 0; k < n; ++k) {
    const t0 = performance.now();
    frame(whole);
    out.push(performance.now() - t0);
  }
  return out;
}

// The frame as base64 RGBA (bottom row first) in one of three modes: shadowed, unshadowed,
// ambient (lights off).
function image(mode) {
  setShadows(mode === "shadowed");
  for (const l of state.lights) l.light.intensity = mode === "ambient" ? 0 : l.intensity;
  frame();
  frame();
  for (const l of state.lights) l.light.intensity = l.intensity;
  let bin = "";
  const p = state.pixels;
  for (let k = 0; k < p.length; k += 0x8000) bin += String.fromCharCode(...p.subarray(k, k + 0x8000));
  return btoa(bin);
}

function dispose() {
  const s = state;
  for (const m of s.materials) { if (m.map) m.map.dispose(); m.dispose(); }
  for (const g of s.geometries) g.dispose();
  s.renderer.dispose();
  state = null;
}

window.bench = { load, time, image };
window.benchReady = true;
