// The parts of three.js the report's 3-D view uses (src/transcalib/report/viewer.js),
// bundled by build_three.sh into three.min.js: one classic script defining the global THREE.
export {
  WebGLRenderer, Scene, PerspectiveCamera, BufferGeometry, BufferAttribute, Points, PointsMaterial,
  LineSegments, LineBasicMaterial, Color, Vector3, ColorManagement, LinearSRGBColorSpace, REVISION,
} from "three";
export { OrbitControls } from "three/examples/jsm/controls/OrbitControls.js";
