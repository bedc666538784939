"""The force a compliant geometry makes at a few overlaps (``hydroilqr check``), measured with
Drake: a point-contact model's stiffness (k N/m, or a force at an overlap) can be matched by
choosing ``hydroelastic_modulus`` until these forces agree.

Each compliant geometry of a collision pair is pressed, face down along its own -z axis,
into a rigid plane by each overlap in turn, in a SceneGraph of its own with its shape and
proximity properties (modulus, resolution hint) exactly as the task builds them. The normal
force is the contact surface's pressure integrated over its area (its triangles: the mean of
their vertex pressures times their area, exact for the linear pressure field). Against
another compliant geometry the force is lower (the two deform in series)."""

from __future__ import annotations

import numpy as np
from pydrake.geometry import (
    AddRigidHydroelasticProperties,
    FramePoseVector,
    GeometryFrame,
    GeometryInstance,
    HalfSpace,
    ProximityProperties,
    SceneGraph,
)
from pydrake.geometry import HydroelasticContactRepresentation as Rep
from pydrake.math import RigidTransform

from hydroilqr.studies.bases import extent_below

OVERLAPS_M = (0.0005, 0.001, 0.002, 0.005)  # the overlaps reported (those within the shape)


def pressed_forces(dyn, gid, overlaps=OVERLAPS_M) -> list[dict]:
    """[{overlap_m, force_n, stiffness_n_per_m (F/overlap), faces}] of the compliant geometry
    ``gid`` of ``dyn`` pressed into a rigid plane; overlaps beyond half its depth are left
    out. [] for a shape whose depth is unknown."""
    inspector = dyn.scene_graph.model_inspector()
    shape = inspector.GetShape(gid)
    depth = extent_below(shape, inspector, gid)
    if depth is None or isinstance(shape, HalfSpace):
        return []
    sg = SceneGraph()
    src = sg.RegisterSource("stiffness")
    frame = sg.RegisterFrame(src, GeometryFrame("pressed"))
    g = sg.RegisterGeometry(src, frame, GeometryInstance(RigidTransform(), shape, "pressed"))
    sg.AssignRole(src, g, ProximityProperties(inspector.GetProximityProperties(gid)))
    plane = sg.RegisterAnchoredGeometry(
        src, GeometryInstance(RigidTransform(), HalfSpace(), "plane")
    )
    rigid = ProximityProperties()
    AddRigidHydroelasticProperties(rigid)
    sg.AssignRole(src, plane, rigid)
    ctx = sg.CreateDefaultContext()
    rows = []
    for d in overlaps:
        if d > 0.5 * depth:
            continue
        poses = FramePoseVector()
        poses.set_value(frame, RigidTransform([0.0, 0.0, depth - d]))
        sg.get_source_pose_port(src).FixValue(ctx, poses)
        query = sg.get_query_output_port().Eval(ctx)
        force, faces = 0.0, 0
        for s in query.ComputeContactSurfaces(Rep.kTriangle):
            mesh, field = s.tri_mesh_W(), s.tri_e_MN()
            for f in range(mesh.num_triangles()):
                tri = mesh.element(f)
                p = np.mean([field.EvaluateAtVertex(tri.vertex(i)) for i in range(3)])
                force += p * mesh.area(f) * abs(mesh.face_normal(f)[2])
            faces += mesh.num_triangles()
        rows.append(
            {"overlap_m": d, "force_n": force, "stiffness_n_per_m": force / d, "faces": faces}
        )
    return rows


def stiffness_report(dyn, geoms: list[dict], pairs: list[dict]) -> list[dict]:
    """For each compliant geometry on a moving body that is in a collision pair: {geometry,
    modulus, resolution_hint, forces: pressed_forces}."""
    in_pairs = {p[k] for p in pairs for k in ("a", "b")}
    world = dyn.plant.world_body().name()
    out = []
    for g in geoms:
        label = f"{g['name']} ({g['body']})"
        if g["kind"] != "compliant" or label not in in_pairs or g["body"] == world:
            continue  # (a compliant ground or wall: what presses into it decides the force)
        forces = pressed_forces(dyn, g["id"])
        if forces:
            out.append(
                {
                    "geometry": label,
                    "modulus": g["modulus"],
                    "resolution_hint": g["resolution_hint"],
                    "forces": forces,
                }
            )
    return out
