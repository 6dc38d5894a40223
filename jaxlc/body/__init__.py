"""The object: shape, materials, attitude and self-shadowing.

* :mod:`~jaxlc.body.mesh` — mesh files → named parts → facets (coplanar
  triangles merged, :mod:`~jaxlc.body.planes`; which facets can be shadowed,
  :mod:`~jaxlc.body.hull`), derived once per file;
* :mod:`~jaxlc.body.brdf` — materials (Lambert, Ashikhmin–Shirley, the
  Cycles-matched AS lobe);
* :mod:`~jaxlc.body.facet_model` — facets with per-facet material
  coefficients and the fused facet sum;
* :mod:`~jaxlc.body.attitude` — body → inertial rotations over time;
* :mod:`~jaxlc.body.octahedral`, :mod:`~jaxlc.body.raycast`,
  :mod:`~jaxlc.body.occlusion`, :mod:`~jaxlc.body.shadow` — self-shadowing by
  precomputed sub-point visibility on a direction grid;
  :mod:`~jaxlc.body.shadow_exact` its exact slow twin (polygon clipping).
"""
