"""The scene's geometry: object meshes in the world frame, clipped at and mirrored across the
ground plane (:mod:`~sonarsim.scene.meshes`)."""
