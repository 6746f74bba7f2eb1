"""Rigid bodies: their geometry and their mechanics, apart from the equations of the material (:mod:`mpmref.physics`).

* :mod:`~mpmref.rigid.polyline` and :mod:`~mpmref.rigid.trimesh`: the bodies' boundaries in 2D (polylines of thin
  segments) and 3D (triangle meshes), their mass properties and the queries CPIC makes of them;
* :mod:`~mpmref.rigid.dynamics`: the rigid state and step that the steppers call, handing each body to its
  dimension's mechanics, :mod:`~mpmref.rigid.dynamics2d` or :mod:`~mpmref.rigid.dynamics3d` (the declared
  interface ``RigidMechanics``).
"""
