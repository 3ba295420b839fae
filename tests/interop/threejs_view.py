#!/usr/bin/env python3
"""View a filmscope GLB in three.js, headless: a manual check of `export-gltf` in a real
renderer (not run by CI; it needs the `three` npm package and a browser with WebGL).

    npm install --prefix DIR three
    python3 tests/interop/threejs_view.py sample.glb DIR        # writes DIR/view.html
    chromium --headless --no-sandbox --use-angle=swiftshader --enable-unsafe-swiftshader \
        --allow-file-access-from-files --user-data-dir=$(mktemp -d) \
        --virtual-time-budget=10000 --hide-scrollbars --window-size=900,640 \
        --screenshot=threejs.png file://DIR/view.html

The page loads the GLB with three.js's GLTFLoader (embedded as base64: no fetch), lights it
with RoomEnvironment, renders the quad seen from about 40 degrees, and prints under the
image what the loader made of the material (MeshPhysicalMaterial iridescence,
iridescenceIOR, thickness range and map, ior).
"""
import base64
import pathlib
import sys

glb = base64.b64encode(pathlib.Path(sys.argv[1]).read_bytes()).decode()
page = f"""<!DOCTYPE html><html><head><meta charset="utf-8">
<script type="importmap">{{"imports": {{"three": "./node_modules/three/build/three.module.js", "three/addons/": "./node_modules/three/examples/jsm/"}}}}</script>
<style>body{{margin:0;background:#fff}}</style></head><body>
<pre id="out">pending</pre>
<script type="module">
import * as THREE from 'three';
import {{ GLTFLoader }} from 'three/addons/loaders/GLTFLoader.js';
import {{ RoomEnvironment }} from 'three/addons/environments/RoomEnvironment.js';
const out = document.getElementById('out');
try {{
const W = 900, H = 600;
const renderer = new THREE.WebGLRenderer({{antialias: true, preserveDrawingBuffer: true}});
renderer.setSize(W, H);
document.body.prepend(renderer.domElement);
const scene = new THREE.Scene();
scene.background = new THREE.Color(0x202020);
const pmrem = new THREE.PMREMGenerator(renderer);
scene.environment = pmrem.fromScene(new RoomEnvironment(), 0.04).texture;
const bytes = Uint8Array.from(atob("{glb}"), c => c.charCodeAt(0));
new GLTFLoader().parse(bytes.buffer, '', (gltf) => {{
  scene.add(gltf.scene);
  let m = null;
  gltf.scene.traverse(o => {{ if (o.isMesh) m = o.material; }});
  const camera = new THREE.PerspectiveCamera(35, W / H, 0.01, 10);
  camera.position.set(0, 0.14, 0.16);
  camera.lookAt(0, 0, 0);
  const done = () => {{
    renderer.render(scene, camera);
    out.textContent = JSON.stringify({{type: m.type, iridescence: m.iridescence, iridescenceIOR: m.iridescenceIOR,
      iridescenceThicknessMinimum: m.iridescenceThicknessMinimum, iridescenceThicknessMaximum: m.iridescenceThicknessMaximum, hasThicknessMap: !!m.iridescenceThicknessMap, ior: m.ior,
      roughness: m.roughness, metalness: m.metalness, revision: THREE.REVISION}});
    document.title = 'rendered';
  }};
  setTimeout(done, 500);
}}, (e) => {{ out.textContent = 'error ' + e; }});
}} catch (e) {{ out.textContent = 'error ' + e; }}
</script></body></html>"""
out = pathlib.Path(sys.argv[2]) / "view.html"
out.write_text(page)
print(f"wrote {out}")
