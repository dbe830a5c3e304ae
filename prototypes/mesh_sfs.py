"""Prototype, not part of the workflow: a multi-view shape from shading on one mesh, the light fitted with its heights.

Its settled form is the workflow's rule ``mesh_light`` (``from_images/mesh_light.py``, docs/table2.md, section 13):
the same model and solver, two casts of three steps, no truth. This script stays for the record's experiments.

An offline experiment on one Table 2 row of a finished run (docs/amica_record.md,
"A shape from shading on one mesh", a first try and a solver that converges). It reads what the image-only path has
(the registration file's cloud points and normals, the reconstruction, the
mission images, and the refinement's output for its start: final light, body
k and image gains), and reads the truth only to print the light's error after
each step.

The surface is the cloud's Poisson surface subdivided to about ``edge_px``
pixel footprints. Every pixel of every image whose ray meets it, ``margin``
pixels (1) inside the silhouette and every cast shadow, lit and seen above
the cosine cuts, is a sample. The unknowns, fitted together by Levenberg-
Marquardt on the sparse Jacobian: each vertex's height along its normal (held
to the Poisson surface by ``sigma_h_px`` and to its neighbours by
``sigma_edge_px``), a log albedo and a k offset per cube of ``cell_px`` (the
offsets held to the body's k by ``sigma_dk``), the body's k, the light (two
angles) and a log gain per image (held by half the mission's stated scatter,
their mean at zero). Lengths are in pixel footprints, so a reconstruction
without navigation priors (its own scale) gets the same settings. Residuals in
log brightness over the sensor's noise plus a relative floor; ``robust`` > 0
weighs them by a Cauchy loss of that many sigmas. Each step solves the damped
normal equations by a sparse LU (``solver=direct``; ``lsqr`` iterates
instead), the damping starting at ``mu0`` and divided by ``mu_down`` after
every accepted step. The samples are cast again after every ``inner`` steps.
At the end it prints the light's standard deviation from the last normal
matrix. Variants: ``warm`` first steps with the light held, ``rigid`` > 0
holding the heights' six rigid motions at zero.

usage (from the repository root, the venv's python; the defaults are the
settings of docs/amica_record.md, "A shape from shading on one mesh: a solver
that converges"):
    python prototypes/mesh_sfs.py RUN_RESULTS IMAGING SET PRIORS [key=value ...]
e.g. python prototypes/mesh_sfs.py runs/tuning/results amica light5_albedo0.15_k1.15 on
"""

import json
import sys
import time
from pathlib import Path

import numpy as np
import scipy.sparse as sp
from scipy.ndimage import binary_erosion
from scipy.sparse.linalg import lsqr, splu

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "workflow"))
import open3d as o3d  # noqa: E402

from asteroid_photometry.experiments.table2 import read_reconstruction  # noqa: E402
from asteroid_photometry.from_images import cloud as cloud_lib  # noqa: E402
from asteroid_photometry.from_images.purity import PurityTest  # noqa: E402
from asteroid_photometry.world.images import read_mission  # noqa: E402
from asteroid_photometry.world.cameras import pixel_rays_cam  # noqa: E402
from asteroid_photometry.world.noise import sensor_from_config  # noqa: E402
from asteroid_photometry.evaluation import metrics  # noqa: E402

results, imaging, set_id, priors = sys.argv[1:5]
opts = dict(a.split("=") for a in sys.argv[5:])
EDGE_PX = float(opts.get("edge_px", 2.5))  # target fine-mesh edge, in pixel footprints
# Lengths in pixel footprints (the reconstruction's own scale: without navigation priors it is not metres).
SIGMA_H_PX = float(opts.get("sigma_h_px", 1.4))  # anchor of each vertex to the Poisson surface
SIGMA_EDGE_PX = float(opts.get("sigma_edge_px", 0.35))  # difference of heights along an edge
CELL_PX = float(opts.get("cell_px", 14.0))  # albedo / k cells
SIGMA_DK = float(opts.get("sigma_dk", 0.025))
FLOOR = float(opts.get("floor", 0.02))  # relative model floor added to the sensor's noise
MIN_COS_E = float(opts.get("min_cos_e", 0.2))
MIN_COS_I = float(opts.get("min_cos_i", 0.1))
OUTER = int(opts.get("outer", 3))
INNER = int(opts.get("inner", 5))
START = opts.get("start", "refined")  # refined | cloud
STRIDE = int(opts.get("stride", 1))
ROBUST = float(opts.get("robust", 3.0))  # Cauchy scale in sigmas, 0: plain
FIX_LIGHT = opts.get("fix_light", "0") == "1"
GAINS = opts.get("gains", "1") == "1"
WARM = int(opts.get("warm", 0))  # the first steps with the light held
MARGIN = int(opts.get("margin", 1))  # pixels kept out inside the silhouette and every cast shadow
RIGID = float(opts.get("rigid", 0.0))  # the heights' six rigid motions held at zero by this (0: not held)
LSQR_ITS = int(opts.get("lsqr_its", 400))
OUT = opts.get("out")  # an .npz for the fit's light (camera frame), body k and gains
EVERY = int(opts.get("every", 1))  # every how many images are sampled (1: all)
ATOL = float(opts.get("atol", 1e-6))
MU0 = float(opts.get("mu0", 1e-5))  # Levenberg-Marquardt's first damping (of the column-scaled system)
MU_DOWN = float(opts.get("mu_down", 10.0))  # its divisor after an accepted step
SOLVER = opts.get("solver", "direct")  # direct (the damped normal equations by sparse LU) | lsqr (iterative, up to LSQR_ITS)

t0 = time.time()
reg = np.load(f"{results}/registration/{imaging}/{set_id}/priors-{priors}.npz")
oriented = cloud_lib.OrientedCloud(reg["points"], reg["normals"], reg["track_length"])
recon = read_reconstruction(f"{results}/reconstruction/{imaging}/{set_id}/priors-{priors}")
mission, images = read_mission(f"{results}/mission/{imaging}/{set_id}")
ref = np.load(f"{results}/refined_cloud/{imaging}/{set_id}/priors-{priors}.npz")
poses = recon.body_to_camera()
K = recon.intrinsics()
idx = sorted(poses)
gains0 = ref["image_gains"] if "image_gains" in ref.files else np.ones(len(images))
images = [images[i] / gains0[i] for i in range(len(images))]
sensor = PurityTest(sensor_from_config(mission["sensor"])) if mission.get("sensor") else None
light = np.array(ref["refined_light_dir_cam"] if START == "refined" else ref["light_dir_cam"], float)
light /= np.linalg.norm(light)
k_glob = float(ref["refined_minnaert_k"])

# The mesh: the cloud's Poisson surface, subdivided to about EDGE_PX pixel footprints.
V0, F0 = cloud_lib.poisson_surface(oriented)
mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(V0), o3d.utility.Vector3iVector(F0))
centres = recon.camera_centres()
dist = np.median([np.linalg.norm(c - V0.mean(0)) for c in centres.values()])
footprint = dist / K.focal_px
edges0 = np.linalg.norm(V0[F0[:, 0]] - V0[F0[:, 1]], axis=1)
n_sub = 0
while np.median(edges0) / 2 ** n_sub > EDGE_PX * footprint and n_sub < 4:
    n_sub += 1
mesh = mesh.subdivide_midpoint(number_of_iterations=n_sub)
mesh.compute_vertex_normals()
P0 = np.asarray(mesh.vertices).copy()
F = np.asarray(mesh.triangles).copy()
D = np.asarray(mesh.vertex_normals).copy()
nv, nf = len(P0), len(F)
cent0 = P0[F].mean(1)
SIGMA_H, SIGMA_EDGE, CELL_M = SIGMA_H_PX * footprint, SIGMA_EDGE_PX * footprint, CELL_PX * footprint
cell_key = np.floor(cent0 / CELL_M).astype(np.int64)
_, cell = np.unique(cell_key, axis=0, return_inverse=True)
cell = cell.ravel()
ncell = cell.max() + 1
print(f"mesh: {len(V0)} -> {nv} vertices, {nf} faces (x{2**n_sub}), median edge {np.median(edges0)/2**n_sub:.2f} m, footprint {footprint:.2f} m/px, {ncell} cells of {CELL_M:.1f}", flush=True)

# Unknowns: h (nv), logA (ncell), k_glob (1), dk (ncell), light (2), log gain (n_images)
n_img = len(images)
o_h, o_a, o_k, o_dk, o_l, o_g = 0, nv, nv + ncell, nv + ncell + 1, nv + 2 * ncell + 1, nv + 2 * ncell + 3
n_par = o_g + n_img
h = np.zeros(nv)
logA = np.zeros(ncell)
dk = np.zeros(ncell)
logg = np.zeros(n_img)
mesh_edges = np.unique(np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1), axis=0)
# The mesh's six rigid motions as heights along the normals (unit rows), for ``rigid``: the reconstruction places the body.
_x = P0 - P0.mean(0)
RIGID_MODES = np.array([m / np.linalg.norm(m) for m in [D[:, j] for j in range(3)] + [np.einsum("ij,ij->i", np.cross(np.eye(3)[j], _x), D) for j in range(3)]])


def face_normals(h):
    P = P0 + h[:, None] * D
    a, b, c = P[F[:, 0]], P[F[:, 1]], P[F[:, 2]]
    cross = np.cross(b - a, c - a)
    norm = np.linalg.norm(cross, axis=1)
    return P, a, b, c, cross, norm


def observe(h, light):
    """Every lit, seen pixel ``MARGIN`` pixels inside the silhouette and the cast shadows: face, image, view, brightness, sigma."""
    P, a, b, c, cross, norm = face_normals(h)
    n = cross / norm[:, None]
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(P.astype(np.float32)), o3d.core.Tensor(F.astype(np.uint32)))
    out = {k: [] for k in ("face", "image", "view", "bright")}
    H, W = images[0].shape
    vv, uu = np.mgrid[0:H:STRIDE, 0:W:STRIDE]
    uu, vv = uu.ravel() + 0.5, vv.ravel() + 0.5
    dirs_cam = pixel_rays_cam(K, uu, vv)
    for i in idx[::EVERY]:
        R = poses[i][:3, :3]
        C = centres[i]
        d = dirs_cam @ R  # R^T d
        rays = np.hstack([np.broadcast_to(C, d.shape), d]).astype(np.float32)
        hit = scene.cast_rays(o3d.core.Tensor(rays))
        t = hit["t_hit"].numpy()
        fid = hit["primitive_ids"].numpy().astype(np.int64)
        on = np.isfinite(t)
        img = images[i][(vv - 0.5).astype(int), (uu - 0.5).astype(int)]
        X = C + t[:, None] * d
        lw = R.T @ light
        fidc = np.where(on, fid, 0)
        cos_i = n[fidc] @ lw
        cos_e = np.einsum("ij,ij->i", n[fidc], -d)
        lit = on & (cos_i > 0)
        # cast shadows
        cand = np.flatnonzero(lit)
        srays = np.hstack([X[cand] + 0.035 * footprint * n[fidc[cand]], np.broadcast_to(lw, (len(cand), 3))]).astype(np.float32)
        shadow = np.isfinite(scene.cast_rays(o3d.core.Tensor(srays))["t_hit"].numpy())
        lit[cand[shadow]] = False
        shape = (len(range(0, H, STRIDE)), len(range(0, W, STRIDE)))
        # MARGIN pixels in from the silhouette and from every shadow edge (the PSF mixes there)
        inner = binary_erosion(on.reshape(shape), np.ones((3, 3)), iterations=MARGIN).ravel() & binary_erosion(lit.reshape(shape), np.ones((3, 3)), iterations=MARGIN).ravel()
        keep = inner & (cos_i >= MIN_COS_I) & (cos_e >= MIN_COS_E) & (img > 0)
        out["face"].append(fid[keep])
        out["image"].append(np.full(int(keep.sum()), i))
        out["view"].append(-d[keep])
        out["bright"].append(img[keep])
    obs = {k: np.concatenate(v) for k, v in out.items()}
    var = sensor.sample_variance(obs["bright"]) if sensor else np.zeros_like(obs["bright"])
    obs["sigma"] = np.sqrt(var / obs["bright"] ** 2 + FLOOR**2)
    return obs


STEP = [0]
Rs = np.array([poses[i][:3, :3] for i in idx])
img_pos = {i: j for j, i in enumerate(idx)}


def light_basis(light):
    e1 = np.cross(light, [0.0, 1.0, 0.0])
    if np.linalg.norm(e1) < 1e-3:
        e1 = np.cross(light, [1.0, 0.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(light, e1)
    return e1, e2


def residual_and_jac(obs, h, logA, k_glob, dk, logg, light, want_jac=True):
    P, a, b, c, cross, norm = face_normals(h)
    n = cross / norm[:, None]
    f = obs["face"]
    ii = obs["image_pos"]
    R = Rs[ii]
    lw = np.einsum("nji,j->ni", R, light)
    nf_ = n[f]
    cos_i = np.einsum("ij,ij->i", nf_, lw)
    cos_e = np.einsum("ij,ij->i", nf_, obs["view"])
    ok = (cos_i > 0.02) & (cos_e > 0.02)
    cos_i = np.maximum(cos_i, 0.02)
    cos_e = np.maximum(cos_e, 0.02)
    kk = k_glob + dk[cell[f]]
    model = logA[cell[f]] + logg[ii] + kk * np.log(cos_i) + (kk - 1) * np.log(cos_e)
    r = (np.log(obs["bright"]) - model) / obs["sigma"]
    r[~ok] = 0.0
    w = np.ones_like(r)
    if ROBUST > 0:
        w = 1.0 / np.sqrt(1.0 + (r / ROBUST) ** 2)
    if not want_jac:
        return r * w, None
    s = -w / obs["sigma"]  # d r / d model
    s[~ok] = 0.0
    g = kk[:, None] * lw / cos_i[:, None] + (kk - 1)[:, None] * obs["view"] / cos_e[:, None]
    # project onto the tangent plane: dn = (I - n n^T) dcross / |cross|
    gt = (g - np.einsum("ij,ij->i", g, nf_)[:, None] * nf_) / norm[f][:, None]
    Da, Db, Dc = D[F[f, 0]], D[F[f, 1]], D[F[f, 2]]
    dca = np.cross(Da, b[f] - c[f])
    dcb = np.cross(Db, c[f] - a[f])
    dcc = np.cross(b[f] - a[f], Dc)
    m = len(r)
    rows, cols, vals = [], [], []
    for col_v, dcross in ((F[f, 0], dca), (F[f, 1], dcb), (F[f, 2], dcc)):
        rows.append(np.arange(m)); cols.append(o_h + col_v); vals.append(s * np.einsum("ij,ij->i", gt, dcross))
    rows.append(np.arange(m)); cols.append(o_a + cell[f]); vals.append(s)
    lk = np.log(cos_i) + np.log(cos_e)
    rows.append(np.arange(m)); cols.append(np.full(m, o_k)); vals.append(s * lk)
    rows.append(np.arange(m)); cols.append(o_dk + cell[f]); vals.append(s * lk)
    e1, e2 = light_basis(light)
    for j, e in enumerate((e1, e2)):
        ew = np.einsum("nji,j->ni", R, e)
        rows.append(np.arange(m)); cols.append(np.full(m, o_l + j)); vals.append(0.0 if (FIX_LIGHT or STEP[0] < WARM) else s * kk * np.einsum("ij,ij->i", nf_, ew) / cos_i)
    rows.append(np.arange(m)); cols.append(o_g + ii); vals.append(s if GAINS else np.zeros(m))
    J = sp.csr_matrix((np.concatenate([np.broadcast_to(v, (m,)) for v in vals]), (np.concatenate(rows), np.concatenate(cols))), shape=(m, n_par))
    return r * w, J


def prior_rows(h, dk, logg):
    blocks_r, blocks_J = [], []
    # anchor
    blocks_r.append(h / SIGMA_H)
    blocks_J.append(sp.csr_matrix((np.full(nv, 1 / SIGMA_H), (np.arange(nv), o_h + np.arange(nv))), shape=(nv, n_par)))
    # edges
    e = mesh_edges
    ne = len(e)
    blocks_r.append((h[e[:, 0]] - h[e[:, 1]]) / SIGMA_EDGE)
    blocks_J.append(sp.csr_matrix((np.concatenate([np.full(ne, 1 / SIGMA_EDGE), np.full(ne, -1 / SIGMA_EDGE)]), (np.tile(np.arange(ne), 2), np.concatenate([o_h + e[:, 0], o_h + e[:, 1]]))), shape=(ne, n_par)))
    blocks_r.append(dk / SIGMA_DK)
    blocks_J.append(sp.csr_matrix((np.full(ncell, 1 / SIGMA_DK), (np.arange(ncell), o_dk + np.arange(ncell))), shape=(ncell, n_par)))
    gs = float(mission.get("gain_sigma") or 0.02) / 2
    blocks_r.append(logg / gs)
    blocks_J.append(sp.csr_matrix((np.full(n_img, 1 / gs), (np.arange(n_img), o_g + np.arange(n_img))), shape=(n_img, n_par)))
    # mean log gain zero (the albedo scale stays the images')
    blocks_r.append(np.array([logg.sum() / 1e-3]))
    blocks_J.append(sp.csr_matrix((np.full(n_img, 1 / 1e-3), (np.zeros(n_img, int), o_g + np.arange(n_img))), shape=(1, n_par)))
    if RIGID > 0:
        blocks_r.append(RIGID_MODES @ h / RIGID)
        blocks_J.append(sp.hstack([sp.csr_matrix(RIGID_MODES / RIGID), sp.csr_matrix((6, n_par - nv))]))
    return np.concatenate(blocks_r), sp.vstack(blocks_J).tocsr()


truth = json.load(open(f"{results}/truth/mission/{imaging}/{set_id}.json"))
light_true = np.array(truth["light_dir_cam"])
spin_cam = np.array(truth["images"][0]["body_to_camera"])[:3, :3] @ np.array([0.0, 0.0, 1.0])


def score(light, tag):
    az, el = metrics.light_error_components_deg(light, light_true, spin_cam)
    err = np.degrees(np.arccos(np.clip(light @ light_true, -1, 1)))
    print(f"  [{tag}] light err {err:.3f} deg (az {az:+.3f}, el {el:+.3f})", flush=True)
    return err, az, el


score(np.array(ref["light_dir_cam"], float) / np.linalg.norm(ref["light_dir_cam"]), "cloud start")
score(light, "workflow final (start here)")

for outer in range(OUTER):
    obs = observe(h, light)
    obs["image_pos"] = np.array([img_pos[i] for i in obs["image"]])
    print(f"outer {outer}: {len(obs['face'])} samples ({time.time()-t0:.0f} s)", flush=True)
    if outer == 0:
        # albedo start: per cell, the mean log residual
        r0, _ = residual_and_jac(obs, h, logA, k_glob, dk, logg, light, want_jac=False)
        resid = r0 * obs["sigma"]
        sums = np.bincount(cell[obs["face"]], weights=resid, minlength=ncell)
        cnts = np.bincount(cell[obs["face"]], minlength=ncell)
        logA = np.where(cnts > 0, sums / np.maximum(cnts, 1), 0.0)
    mu = MU0 if outer == 0 else mu
    for inner in range(INNER):
        STEP[0] = outer * INNER + inner
        r, J = residual_and_jac(obs, h, logA, k_glob, dk, logg, light)
        pr, PJ = prior_rows(h, dk, logg)
        cost = 0.5 * (r @ r + pr @ pr)
        A = sp.vstack([J, PJ]).tocsr()
        rhs = -np.concatenate([r, pr])
        # column scaling
        colnorm = np.sqrt(np.asarray(A.multiply(A).sum(0)).ravel())
        colnorm[colnorm == 0] = 1.0
        As = A @ sp.diags(1 / colnorm)
        if SOLVER == "direct":
            normal = (As.T @ As).tocsc()
            grad = As.T @ rhs
        for attempt in range(6):
            if SOLVER == "direct":
                ts = time.time()
                y = splu((normal + mu * sp.identity(n_par, format="csc")).tocsc(), permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options=dict(SymmetricMode=True)).solve(grad)
                sol = (y, None, f"direct {time.time() - ts:.1f} s")
            else:
                sol = lsqr(As, rhs, damp=np.sqrt(mu), atol=ATOL, btol=ATOL, iter_lim=LSQR_ITS)
            x = sol[0] / colnorm
            h_n = h + x[o_h:o_h + nv]
            logA_n = logA + x[o_a:o_a + ncell]
            k_n = k_glob + x[o_k]
            dk_n = dk + x[o_dk:o_dk + ncell]
            e1, e2 = light_basis(light)
            l_n = light + x[o_l] * e1 + x[o_l + 1] * e2
            l_n /= np.linalg.norm(l_n)
            g_n = logg + x[o_g:o_g + n_img]
            rn, _ = residual_and_jac(obs, h_n, logA_n, k_n, dk_n, g_n, l_n, want_jac=False)
            prn, _ = prior_rows(h_n, dk_n, g_n)
            cost_n = 0.5 * (rn @ rn + prn @ prn)
            if cost_n < cost:
                h, logA, k_glob, dk, light, logg = h_n, logA_n, k_n, dk_n, l_n, g_n
                mu = max(mu / MU_DOWN, 1e-6)
                break
            mu *= 10
        print(f"  inner {inner}: cost {cost:.4g} -> {cost_n:.4g} (mu {mu:.1e}, lsqr its {sol[2]}), k {k_glob:.4f}, |h| rms {np.sqrt(np.mean(h**2)):.3f} m, gains sd {np.std(logg):.4f} ({time.time()-t0:.0f} s)", flush=True)
        score(light, f"outer {outer} inner {inner}")
    rr, _ = residual_and_jac(obs, h, logA, k_glob, dk, logg, light, want_jac=False)
    rel = rr * obs["sigma"]
    P_, a_, b_, c_, cr_, no_ = face_normals(h)
    ce = np.einsum("ij,ij->i", (cr_ / no_[:, None])[obs["face"]], obs["view"])
    q = np.percentile(np.abs(rel), [50, 90, 99])
    print(f"  rel residual: rms {np.sqrt(np.mean(rel**2)):.4f}, |.| 50/90/99% {q[0]:.4f} {q[1]:.4f} {q[2]:.4f}; by cos_e band (mean, rms):", " ".join(f"[{lo:.1f}: {rel[(ce>=lo)&(ce<lo+0.2)].mean():+.4f} {np.sqrt(np.mean(rel[(ce>=lo)&(ce<lo+0.2)]**2)):.4f}]" for lo in (0.2, 0.4, 0.6, 0.8)), flush=True)
# The light's standard deviation from the last samples' Gauss-Newton normal matrix (heights, albedo, k and gains marginalised).
r, J = residual_and_jac(obs, h, logA, k_glob, dk, logg, light)
pr, PJ = prior_rows(h, dk, logg)
A = sp.vstack([J, PJ]).tocsr()
colnorm = np.sqrt(np.asarray(A.multiply(A).sum(0)).ravel())
colnorm[colnorm == 0] = 1.0
As = A @ sp.diags(1 / colnorm)
lu = splu((As.T @ As + 1e-9 * sp.identity(n_par, format="csc")).tocsc(), permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options=dict(SymmetricMode=True))
unit = np.zeros((n_par, 2))
unit[o_l, 0] = unit[o_l + 1, 1] = 1.0
cov = lu.solve(unit)[o_l:o_l + 2] / np.outer(colnorm[o_l:o_l + 2], colnorm[o_l:o_l + 2])
sd = np.degrees(np.sqrt(np.linalg.eigvalsh(cov)))
print(f"light sd from the fit: {sd[0]:.3f} / {sd[1]:.3f} deg (principal axes); k {k_glob:.4f}", flush=True)
if OUT:
    np.savez(OUT, light_dir_cam=light, minnaert_k=k_glob, log_gains=logg, light_sd_deg=sd)
print(f"done in {time.time()-t0:.0f} s")
