"""The mesh fit's light (from_images.mesh_light): its Jacobian, its convergence on rendered images of a sphere, the stage's gate,
the final cloud's choice."""

import numpy as np
import open3d as o3d
import pytest

from asteroid_photometry.core import files
from asteroid_photometry.core.failures import DataFailure
from asteroid_photometry.experiments import table2
from asteroid_photometry.experiments.table2 import MESH_LIGHT_MIN_K, final_cloud_path, mesh_light_of, mesh_light_psf, mesh_light_skipped
from asteroid_photometry.from_images import mesh_light
from asteroid_photometry.from_images.refine import PureSampleCloud
from asteroid_photometry.world.cameras import Intrinsics, pixel_rays_cam
from asteroid_photometry.world.degrade import apply_psf, psf_kernel
from synthetic_helpers import equatorial_poses


def _sphere(subdivisions: int):
    mesh = o3d.geometry.TriangleMesh.create_sphere(radius=1.0, resolution=subdivisions)
    mesh.compute_vertex_normals()
    return np.asarray(mesh.vertices).copy(), np.asarray(mesh.triangles).copy(), np.asarray(mesh.vertex_normals).copy()


def _ring(n_images: int, distance: float):
    """Cameras on the equator looking at the origin: body-to-camera poses and centres, by image index."""
    poses = equatorial_poses(n_images, distance)
    return poses, {i: -pose[:3, :3].T @ pose[:3, 3] for i, pose in poses.items()}


def _light(angle_deg: float):
    a = np.radians(angle_deg)
    return np.array([np.sin(a), 0.0, -np.cos(a)])


def _render_sphere(poses, centres, intrinsics: Intrinsics, light_cam, albedo: float, k: float, noise: float, seed: int):
    """Images of the unit sphere (the exact sphere, not a mesh) under a Minnaert law, with relative Gaussian noise."""
    rng = np.random.default_rng(seed)
    vv, uu = np.mgrid[0 : intrinsics.height, 0 : intrinsics.width]
    rays = pixel_rays_cam(intrinsics, uu.ravel() + 0.5, vv.ravel() + 0.5)
    images = []
    for i in sorted(poses):
        R, C = poses[i][:3, :3], centres[i]
        d = rays @ R
        b = d @ C
        disc = b**2 - (C @ C - 1.0)
        hit = disc > 0
        t = -b - np.sqrt(np.where(hit, disc, 0.0))
        n = C + t[:, None] * d
        cos_i = n @ (R.T @ light_cam)
        cos_e = -np.einsum("ij,ij->i", n, d)
        lit = hit & (cos_i > 0) & (cos_e > 0)
        value = np.where(lit, albedo * np.maximum(cos_i, 1e-9) ** k * np.maximum(cos_e, 1e-9) ** (k - 1), 0.0)
        value = value * (1 + noise * rng.standard_normal(value.shape))
        images.append(value.reshape(intrinsics.height, intrinsics.width))
    return images


def test_jacobian_matches_finite_differences():
    vertices, triangles, normals = _sphere(6)
    settings = mesh_light.MeshLightSettings(robust=0.0, cell_px=20.0)
    poses, centres = _ring(4, 5.0)
    rotations = np.array([poses[i][:3, :3] for i in sorted(poses)])
    problem = mesh_light._MeshProblem(vertices, triangles, normals, 0.02, 4, 0.02, settings)
    rng = np.random.default_rng(1)
    m = 300
    face = rng.integers(0, len(triangles), m)
    image = rng.integers(0, 4, m)
    view = rotations[image][:, 2, :] * -1.0  # towards the camera, body frame
    samples = mesh_light._Samples(face, image, view, rng.normal(-1.0, 0.1, m), np.full(m, 0.05))
    cell = problem.cell[face]
    samples.columns = np.column_stack([triangles[face], problem.o_a + cell, np.full(m, problem.o_k), problem.o_dk + cell, np.full(m, problem.o_l), np.full(m, problem.o_l + 1), problem.o_g + image])
    state = mesh_light._State(
        rng.normal(0, 0.01, problem.nv), rng.normal(-0.5, 0.1, problem.ncell), 0.85, rng.normal(0, 0.02, problem.ncell), _light(20.0), rng.normal(0, 0.01, 4),
    )
    # Keep only samples the state sees and lights well (the clamp's kink is not differentiable).
    P, a, b, c, cross, norm = problem.surface(state.h)
    n = cross / norm[:, None]
    lw = np.einsum("nji,j->ni", rotations, state.light)[image]
    good = (np.einsum("ij,ij->i", n[face], lw) > 0.2) & (np.einsum("ij,ij->i", n[face], view) > 0.2)
    assert good.sum() > 20
    samples = mesh_light._Samples(face[good], image[good], view[good], samples.log_brightness[good], samples.sigma[good], samples.columns[good])
    r0, _, J = mesh_light._residuals(problem, samples, state, rotations, jacobian=True)
    J = J.toarray()
    used = np.unique(samples.columns)
    eps = 1e-6
    for column in used:
        x = np.zeros(problem.n_par)
        x[column] = eps
        r1, _, _ = mesh_light._residuals(problem, samples, state.stepped(problem, x), rotations, jacobian=False)
        x[column] = -eps
        r2, _, _ = mesh_light._residuals(problem, samples, state.stepped(problem, x), rotations, jacobian=False)
        numeric = (r1 - r2) / (2 * eps)
        np.testing.assert_allclose(J[:, column], numeric, rtol=2e-4, atol=2e-4 * np.abs(numeric).max() + 1e-9, err_msg=f"column {column}")


def test_fit_recovers_the_light_of_a_rendered_sphere():
    """Started 2 degrees off, the fit finds the light of noisy images of a sphere (rendered exactly, fitted as a mesh).

    What is left (0.32 deg, k 0.878 at 1 % noise; 0.13 deg and 0.895 noise-free on a finer start) is the coarse
    start's flat facets the heights' priors hold to; more steps do not change it."""
    intrinsics = Intrinsics(128, 128, 240.0, 64.0, 64.0)
    poses, centres = _ring(16, 5.0)
    true_light = _light(15.0)
    images = _render_sphere(poses, centres, intrinsics, true_light, 0.3, 0.9, noise=0.01, seed=2)
    vertices, triangles, _ = _sphere(12)
    start = _light(15.0) + np.array([0.0, np.sin(np.radians(2.0)), 0.0])
    start /= np.linalg.norm(start)
    fit = mesh_light.fit_mesh_light(
        vertices, triangles, centres, poses, intrinsics, images, lambda value: (0.01 * value) ** 2, start, 0.8, 0.0,
        mesh_light.MeshLightSettings(outer=2, inner=4),
    )
    error_deg = np.degrees(np.arccos(np.clip(fit.light_dir_cam @ true_light, -1, 1)))
    assert error_deg < 0.5
    assert abs(fit.minnaert_k - 0.9) < 0.04
    assert fit.n_steps >= 4
    # The fitted surface comes back with it, on the sphere's as closely as the coarse start's flat facets allow.
    assert fit.vertices.shape == (fit.n_vertices, 3) and fit.triangles.max() == fit.n_vertices - 1
    assert np.abs(np.linalg.norm(fit.vertices, axis=1) - 1.0).max() < 0.02


def test_fit_recovers_the_gains_of_a_rendered_sphere():
    """Each image of the sphere off by a calibration gain (3 % scatter): the fit's gains follow them, in log, to well
    under their scatter (the common factor trades with the albedo: compared after taking each side's mean off)."""
    intrinsics = Intrinsics(128, 128, 240.0, 64.0, 64.0)
    poses, centres = _ring(16, 5.0)
    true_light = _light(15.0)
    images = _render_sphere(poses, centres, intrinsics, true_light, 0.3, 0.9, noise=0.01, seed=4)
    true_log_gains = 0.03 * np.random.default_rng(5).standard_normal(len(images))
    images = [image * np.exp(g) for image, g in zip(images, true_log_gains)]
    vertices, triangles, _ = _sphere(12)
    fit = mesh_light.fit_mesh_light(
        vertices, triangles, centres, poses, intrinsics, images, lambda value: (0.01 * value) ** 2, true_light, 0.9, 0.03,
        mesh_light.MeshLightSettings(outer=2, inner=4),
    )
    np.testing.assert_array_equal(fit.image_indices, np.arange(len(images)))
    error = (fit.log_gains - fit.log_gains.mean()) - (true_log_gains - true_log_gains.mean())
    assert np.sqrt(np.mean(error**2)) < 0.2 * np.std(true_log_gains)


def test_the_mesh_stages_gains_are_by_image_at_geometric_mean_one(tmp_path):
    path = tmp_path / "mesh_light.npz"
    log_gains = np.array([0.02, 0.05, -0.01])
    files.savez(path, status=np.str_("ok"), applied=True, reason=np.str_(""), light_dir_cam=np.array([0.0, 0.0, -1.0]), log_gains=log_gains, image_indices=np.array([0, 2, 3]))
    light, gains = mesh_light_of(path, 5)
    np.testing.assert_array_equal(light, [0.0, 0.0, -1.0])
    np.testing.assert_array_equal(gains[[1, 4]], 1.0)  # images the fit did not use
    np.testing.assert_allclose(np.prod(gains[[0, 2, 3]]), 1.0)
    np.testing.assert_allclose(gains[2] / gains[0], np.exp(0.03))
    files.savez(path, status=np.str_("ok"), applied=False, reason=np.str_("noise-free"))
    assert mesh_light_of(path, 5) is None


def test_the_final_fit_reads_the_refitted_cloud_only_where_there_is_one(tmp_path):
    refined, final = tmp_path / "refined.npz", tmp_path / "final.npz"
    files.savez(final, status=np.str_("ok"), refitted=False, reason=np.str_("images with a sensor model"))
    assert final_cloud_path(refined, final) == refined
    files.savez(final, points=np.zeros((3, 3)), normals=np.zeros((3, 3)))
    assert final_cloud_path(refined, final) == final
    assert final_cloud_path(refined, None) == refined
    files.savez(final, status=np.str_("failed"), reason=np.str_("the refit kept 2 points"))
    with pytest.raises(DataFailure, match="kept 2 points"):
        final_cloud_path(refined, final)


def test_too_few_pixels_is_a_clear_error():
    intrinsics = Intrinsics(16, 16, 10.0, 8.0, 8.0)
    poses, centres = _ring(2, 50.0)
    images = [np.zeros((16, 16)) for _ in poses]
    vertices, triangles, _ = _sphere(4)
    with pytest.raises(ValueError, match="usable pixels"):
        mesh_light.fit_mesh_light(vertices, triangles, centres, poses, intrinsics, images, None, _light(0.0), 0.9, 0.0)
    # A surface beside every image (none of its pixels cast) fails the same way, naming the cause.
    with pytest.raises(ValueError, match="usable pixels.*none of the 2 images"):
        mesh_light.fit_mesh_light(vertices + [0.0, 0.0, 200.0], triangles, centres, poses, intrinsics, images, None, _light(0.0), 0.9, 0.0)


def _pure(k: float) -> PureSampleCloud:
    cloud = PureSampleCloud.__new__(PureSampleCloud)
    object.__setattr__(cloud, "refined_minnaert_k", k)
    return cloud


def test_the_mission_psf_is_its_stated_core_to_three_sigma():
    np.testing.assert_allclose(mesh_light_psf({"psf_fwhm_px": 1.5}), psf_kernel(1.5, radius_px=2))
    assert mesh_light_psf({"psf_fwhm_px": 3.0}).shape == (9, 9)  # 3 sigma = 3.8 px
    assert mesh_light_psf({"psf_fwhm_px": 0.0}) is None
    assert mesh_light_psf({"psf_fwhm_px": None}) is None and mesh_light_psf({}) is None


def test_the_stage_fits_under_the_missions_psf_and_gains(monkeypatch):
    seen = {}
    monkeypatch.setattr(table2.cloud_lib, "poisson_surface", lambda oriented, depth: (np.zeros((3, 3)), np.array([[0, 1, 2]])))
    monkeypatch.setattr(table2.mesh_light, "fit_mesh_light", lambda *args, **kwargs: seen.update(args=args, kwargs=kwargs))

    class Recon:
        def camera_centres(self):
            return {0: np.zeros(3)}

        def body_to_camera(self):
            return {0: np.eye(4)}

        def intrinsics(self):
            return Intrinsics(8, 8, 10.0, 4.0, 4.0)

    pure = _pure(0.9)
    object.__setattr__(pure, "image_gains", np.array([2.0]))
    object.__setattr__(pure, "refined_light_dir_cam", np.array([0.0, 0.0, -1.0]))
    table2.fit_mesh_light_on(pure, None, Recon(), {"psf_fwhm_px": 1.5, "gain_sigma": 0.02}, [np.full((8, 8), 4.0)])
    np.testing.assert_allclose(seen["kwargs"]["psf"], psf_kernel(1.5, radius_px=2))
    np.testing.assert_allclose(seen["args"][5][0], 2.0)  # the image over the refinement's gain
    assert seen["args"][-1] == 0.02
    table2.fit_mesh_light_on(pure, None, Recon(), {"psf_fwhm_px": 0.0, "gain_sigma": 0.0}, [np.full((8, 8), 4.0)])
    assert seen["kwargs"]["psf"] is None


def test_gate_skips_a_k_near_one_half():
    assert "below" in mesh_light_skipped(_pure(MESH_LIGHT_MIN_K - 0.01))
    assert mesh_light_skipped(_pure(MESH_LIGHT_MIN_K + 0.01)) is None
    assert "below" in mesh_light_skipped(_pure(float("nan")))


def _sphere_samples(problem, triangles, n_images: int, rng, per_face: int = 3):
    """Samples on every face of a sphere's mesh from ``n_images`` views about the equator, with their Jacobian columns."""
    face = np.repeat(np.arange(len(triangles)), per_face)
    image = rng.integers(0, n_images, len(face))
    angles = 2 * np.pi * image / n_images
    view = np.column_stack([np.sin(angles), np.zeros(len(face)), np.cos(angles)])
    samples = mesh_light._Samples(face, image, view, rng.normal(-1.0, 0.05, len(face)), np.full(len(face), 0.05))
    cell = problem.cell[face]
    samples.columns = np.column_stack([triangles[face], problem.o_a + cell, np.full(len(face), problem.o_k), problem.o_dk + cell,
                                       np.full(len(face), problem.o_l), np.full(len(face), problem.o_l + 1), problem.o_g + image])
    return samples


def test_normal_matrix_is_the_jacobians_and_the_priors():
    """The step's matrix, assembled from sums of products by face, by face and image and by image on a pattern made once,
    is J'J + P'P; scaled by its columns' norms, with the damping on its diagonal, it is (JS)'(JS) + (PS)'(PS) + damping I;
    and the same pattern serves another Jacobian of the same samples."""
    import scipy.sparse as sp

    rng = np.random.default_rng(3)
    vertices, triangles = _geodesic_sphere(2)
    problem = mesh_light._MeshProblem(vertices, triangles, vertices.copy(), 0.05, 5, 0.02, mesh_light.MeshLightSettings(cell_px=4.0))
    assert problem.ncell > 3
    samples = _sphere_samples(problem, triangles, 5, rng)
    keep = rng.uniform(size=len(samples.face)) < 0.6  # some faces unseen, some by one image only
    samples = mesh_light._Samples(samples.face[keep], samples.image[keep], samples.view[keep], samples.log_brightness[keep], samples.sigma[keep], samples.columns[keep])
    normal_matrix = mesh_light._NormalMatrix(problem, samples)
    for _ in range(2):
        values = rng.normal(size=samples.columns.size)
        J = sp.csr_matrix((values, samples.columns.ravel(), np.arange(0, values.size + 1, 9)), shape=(len(samples.face), problem.n_par))
        expected = (J.T @ J + problem.prior.T @ problem.prior).toarray()
        normal = normal_matrix(values)
        assert isinstance(normal, sp.csc_matrix)
        np.testing.assert_allclose(normal.toarray(), expected, rtol=1e-12, atol=1e-12)
        scaled, norms = normal_matrix.scaled(values)
        np.testing.assert_allclose(norms, np.sqrt(np.where(np.diag(expected) > 0, np.diag(expected), 1.0)), rtol=1e-12)
        S = np.diag(1 / norms)
        gradient = rng.normal(size=problem.n_par)
        order = rng.permutation(problem.n_par)  # the elimination order changes the arithmetic, not the step
        damped = S @ expected @ S + 1e-3 * np.eye(problem.n_par)
        np.testing.assert_allclose(mesh_light._solve(scaled, gradient, 1e-3, order), np.linalg.solve(damped, gradient), rtol=1e-8, atol=1e-10)
        # The damping is added to a copy: the matrix is the same for the next attempt.
        np.testing.assert_allclose(scaled.toarray() + 1e-3 * np.eye(problem.n_par), damped, rtol=1e-12, atol=1e-14)
    # Every diagonal entry is stored, an unseen vertex's too (its height held by the priors alone).
    assert np.all(normal_matrix.row[normal_matrix.diagonal] == np.arange(problem.n_par))


def test_step_in_single_precision_is_refined_to_double(monkeypatch, caplog):
    """The step from a single precision LU, refined by preconditioned conjugate gradients, is the double precision
    solution on a system as ill-conditioned as the fit's (its damping 1e-6 against a unit diagonal), far closer than the
    single precision LU alone; where the gradients cannot converge, the step falls back to a double precision LU."""
    import logging

    import scipy.sparse as sp
    from scipy.sparse.linalg import splu

    rng = np.random.default_rng(5)
    n = 400
    # A surface-like matrix: a grid's graph Laplacian (singular: a constant is free) with a few dense rows and columns
    # (the shared unknowns) and a weak prior, scaled to a unit diagonal as the fit scales its columns.
    side = 20
    grid = sp.diags([-1.0, -1.0, -1.0, -1.0], [-side, -1, 1, side], shape=(n, n), format="lil")
    for i in range(side, n, side):
        grid[i, i - 1] = grid[i - 1, i] = 0.0
    grid = grid.tocsc()
    laplacian = sp.diags(-np.asarray(grid.sum(axis=1)).ravel()) + grid
    dense = rng.normal(size=(n, 3)) * 0.05
    matrix = sp.csc_matrix(laplacian + sp.csc_matrix(dense @ dense.T) + 1e-4 * sp.eye(n))
    norms = np.sqrt(matrix.diagonal())
    scaled = sp.csc_matrix(sp.diags(1 / norms) @ matrix @ sp.diags(1 / norms))
    gradient = rng.normal(size=n)
    order = rng.permutation(n)
    damping = 1e-6
    damped = scaled.toarray() + damping * np.eye(n)
    expected = np.linalg.solve(damped, gradient)
    assert np.linalg.cond(damped) > 1e3
    step = mesh_light._solve(scaled, gradient, damping, order)
    error = np.linalg.norm(step - expected) / np.linalg.norm(expected)
    single = splu(sp.csc_matrix(damped, dtype=np.float32), permc_spec="NATURAL", diag_pivot_thresh=0.0).solve(gradient.astype(np.float32))
    single_error = np.linalg.norm(single - expected) / np.linalg.norm(expected)
    assert error < 1e-10 < 1e-3 * single_error
    # A residual out of reach: the double precision LU's step, and the log says so.
    monkeypatch.setattr(mesh_light, "STEP_RTOL", 1e-30)
    monkeypatch.setattr(mesh_light, "STEP_MAX_ITERATIONS", 3)
    with caplog.at_level(logging.INFO, logger=mesh_light.log.name):
        fallback = mesh_light._solve(scaled, gradient, damping, order)
    assert "made in double precision" in caplog.text
    np.testing.assert_allclose(fallback, expected, rtol=1e-9, atol=1e-12 * np.abs(expected).max())


def test_step_falls_back_where_single_precision_cannot_hold_a_pivot(caplog):
    """A pivot below single precision's range (here 1e-50, zero as a float32) makes its LU singular: the step is the
    double precision LU's."""
    import logging

    import scipy.sparse as sp

    normal = sp.csc_matrix(np.diag([0.0, 1.0, 2.0]))
    gradient = np.array([1e-50, 1.0, 1.0])
    with caplog.at_level(logging.INFO, logger=mesh_light.log.name):
        step = mesh_light._solve(normal, gradient, 1e-50, np.array([2, 0, 1]))
    assert "made in double precision" in caplog.text
    np.testing.assert_allclose(step, [1.0, 1.0, 0.5], rtol=1e-12)


def _geodesic_sphere(subdivisions: int):
    mesh = o3d.geometry.TriangleMesh.create_icosahedron(radius=1.0).subdivide_midpoint(number_of_iterations=subdivisions)
    vertices = np.asarray(mesh.vertices) / np.linalg.norm(np.asarray(mesh.vertices), axis=1, keepdims=True)
    return vertices, np.asarray(mesh.triangles).copy()


@pytest.mark.parametrize("cell_px, of_colamd", [(14.0, 0.9), (mesh_light.MeshLightSettings().cell_px, 1.0)])
def test_elimination_order_dissects_the_surface(cell_px, of_colamd):
    """The step's elimination order: every unknown once, the shared ones (k, light, gains) last, each cell's albedo and
    k offset side by side; and an LU of the step's matrix in this order fills in less than in COLAMD's (what the fit
    used before; on this sphere of 10,242 vertices 0.76 of it with cells of 14 footprints, 0.97 with the default 7,
    whose cells' albedos and k offsets are two in five of the unknowns) and far less than in the mesh's own numbering (0.18)."""
    from scipy.sparse.linalg import splu

    vertices, triangles = _geodesic_sphere(5)
    settings = mesh_light.MeshLightSettings(cell_px=cell_px)
    problem = mesh_light._MeshProblem(vertices, triangles, vertices.copy(), 0.01, 6, 0.02, settings)
    order = problem.order
    np.testing.assert_array_equal(np.sort(order), np.arange(problem.n_par))
    np.testing.assert_array_equal(order[-9:], [problem.o_k, problem.o_l, problem.o_l + 1, *(problem.o_g + np.arange(6))])
    position = np.argsort(order)
    cells = np.arange(problem.ncell)
    np.testing.assert_array_equal(np.abs(position[problem.o_dk + cells] - position[problem.o_a + cells]), 1)
    # The step's matrix: samples on every face from six views around the equator.
    samples = _sphere_samples(problem, triangles, 6, np.random.default_rng(2))
    rotations = np.array([np.eye(3)] * 6)
    state = mesh_light._State(np.zeros(problem.nv), np.zeros(problem.ncell), 0.8, np.zeros(problem.ncell), _light(0.0), np.zeros(6))
    _, _, J = mesh_light._residuals(problem, samples, state, rotations, jacobian=True)
    normal = mesh_light._NormalMatrix(problem, samples)(J.data)
    normal.setdiag(normal.diagonal() + 1.0)

    def fill(matrix, spec):
        lu = splu(matrix, permc_spec=spec, diag_pivot_thresh=0.0, options=dict(SymmetricMode=True))
        return lu.L.nnz + lu.U.nnz

    dissected = fill(normal[order][:, order].tocsc(), "NATURAL")
    assert dissected < of_colamd * fill(normal, "COLAMD")
    assert dissected < 0.25 * fill(normal, "NATURAL")


def test_blur_matrix_is_the_psf_over_the_support():
    """Each sample's row of the blur matrix weighs its support pixels as the PSF blurs an image in which every other
    pixel (sky, shadow) is black."""
    rng = np.random.default_rng(3)
    shape = (2, 12, 10)
    values = rng.uniform(0.5, 1.5, shape)
    support = np.flatnonzero(rng.uniform(size=values.size) < 0.7)
    samples = rng.choice(support, 40, replace=False)
    psf = psf_kernel(1.5, radius_px=2)
    blur = mesh_light._blur_matrix(psf, samples, support, shape)
    shown = np.zeros(values.size)
    shown[support] = values.ravel()[support]
    expected = np.concatenate([apply_psf(image, psf).ravel() for image in shown.reshape(shape)])[samples]
    np.testing.assert_allclose(blur @ values.ravel()[support], expected, rtol=1e-12, atol=1e-12)


def test_the_blurred_model_fits_blurred_images_better():
    """At the true light, k and albedo, the model blurred by the camera's PSF leaves a smaller misfit to PSF-blurred
    images of a sphere than the sharp model does (at the limb and the shadows above all)."""
    intrinsics = Intrinsics(96, 96, 180.0, 48.0, 48.0)
    poses, centres = _ring(4, 5.0)
    light = _light(30.0)
    psf = psf_kernel(1.5, radius_px=2)
    images = [apply_psf(image, psf_kernel(1.5)) for image in _render_sphere(poses, centres, intrinsics, light, 0.3, 0.9, noise=0.0, seed=4)]
    vertices, triangles, normals = _sphere(40)
    settings = mesh_light.MeshLightSettings(robust=0.0, floor=0.01)
    rotations = np.array([poses[i][:3, :3] for i in sorted(poses)])
    centre_array = np.array([centres[i] for i in sorted(poses)])
    problem = mesh_light._MeshProblem(vertices, triangles, normals, 1 / 36.0, 4, 0.0, settings)
    state = mesh_light._State(np.zeros(problem.nv), np.full(problem.ncell, np.log(0.3)), 0.9, np.zeros(problem.ncell), light, np.zeros(4))
    misfit = {}
    for name, kernel in (("sharp", None), ("blurred", psf)):
        samples = mesh_light._cast(problem, state.h, light, rotations, centre_array, intrinsics, images, lambda value: np.zeros_like(value), kernel)
        r, _, _ = mesh_light._residuals(problem, samples, state, rotations, jacobian=False)
        misfit[name] = np.sqrt(np.mean(r**2)) * settings.floor
    assert misfit["blurred"] < 0.6 * misfit["sharp"], misfit


def test_the_cast_window_holds_every_pixel_that_sees_the_surface():
    """Every pixel whose ray meets the surface lies in the window ``_cast`` casts (with its pad around), the window is
    no wider than that, and a surface behind the camera or beside the image gets the whole image or none of it."""
    vertices, triangles, _ = _sphere(20)
    lobes = 1.0 + 0.25 * np.cos(3 * np.arctan2(vertices[:, 1], vertices[:, 0]))  # three lobes: not convex
    vertices = vertices * lobes[:, None] * np.array([1.6, 0.8, 0.6]) + np.array([0.3, -0.2, 0.1])  # elongated, off the optical axis
    intrinsics = Intrinsics(width=96, height=80, focal_px=100.0, cx=48.0, cy=40.0)
    poses, centres = _ring(5, 6.0)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(vertices.astype(np.float32)), o3d.core.Tensor(triangles.astype(np.uint32)))
    vv, uu = np.mgrid[0 : intrinsics.height, 0 : intrinsics.width]
    rays = pixel_rays_cam(intrinsics, uu.ravel() + 0.5, vv.ravel() + 0.5)
    corners = mesh_light._hull_corners(vertices)
    assert len(corners) < len(vertices)
    for i in sorted(poses):
        R, C = poses[i][:3, :3], centres[i]
        d = rays @ R
        seen = np.isfinite(scene.cast_rays(o3d.core.Tensor(np.hstack([np.broadcast_to(C, d.shape), d]).astype(np.float32)))["t_hit"].numpy())
        rows, columns = np.divmod(np.flatnonzero(seen), intrinsics.width)
        assert len(rows) > 100
        (v0, v1), (u0, u1) = mesh_light._window(corners, R, C, intrinsics, intrinsics.height, intrinsics.width, pad=2)
        assert v0 <= rows.min() - 2 and rows.max() + 2 < v1 and u0 <= columns.min() - 2 and columns.max() + 2 < u1
        assert v1 - v0 <= rows.max() - rows.min() + 8 and u1 - u0 <= columns.max() - columns.min() + 8
    R, C = poses[0][:3, :3], centres[0]
    assert mesh_light._window(corners, R, -C, intrinsics, intrinsics.height, intrinsics.width, pad=2) == ((0, 80), (0, 96))  # behind
    beside = corners + 50.0 * (R.T @ np.array([1.0, 0.0, 0.0]))
    (v0, v1), (u0, u1) = mesh_light._window(beside, R, C, intrinsics, intrinsics.height, intrinsics.width, pad=2)
    assert u1 == u0
