# Peer timing for README: Open3D segment_plane on a cloud laid out like benches/segment.rs.
# Run: OMP_NUM_THREADS=2 python3 benches/peers/open3d_segment_plane.py (needs pip install open3d).
# Same layout as benches/segment.rs: 1,100-wide raster, 0.185 mm spacing, sigma 0.025 along y/z.
import numpy as np, open3d as o3d, time
rng = np.random.default_rng(1)
w, p = 1100, 0.185
x = (np.arange(w) - w/2) * p
def face(rows, f):
    pts = []
    for r in range(rows):
        pts.append(f(x, r))
    return np.concatenate(pts)
zB = lambda r: -71.04 + r*p
B = face(384, lambda x, r: np.stack([x, np.full_like(x, 1.0) + rng.normal(0, .025, x.size), np.full_like(x, -71.04 + r*p)], 1))
A = face(384, lambda x, r: np.stack([x, np.zeros_like(x) + rng.normal(0, .025, x.size), np.full_like(x, r*p)], 1))
T = face(384, lambda x, r: np.stack([x, np.full_like(x, r*p), np.full_like(x, 71.04) + rng.normal(0, .025, x.size)], 1))
pts = np.concatenate([B, A, T])[:1266606]
pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
print("points", len(pc.points))
for it in (100, 1000):
    best = 1e9
    for _ in range(3):
        t = time.perf_counter(); pc.segment_plane(distance_threshold=0.1, ransac_n=3, num_iterations=it); best = min(best, time.perf_counter() - t)
    print(f"open3d {o3d.__version__} segment_plane {it} iterations, one plane: {best*1000:.0f} ms (best of 3)")
