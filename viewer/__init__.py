"""The polyscope viewer: look at every method's result before believing a table.

Views (each behind ``facegeom view <name>``; ``--screenshot PATH`` renders headless):

- :class:`facegeom.viewer.drive.DriveView`: source | every deformer | true target, per-vertex
  error colours (mm), markers dragged or nudged live through each deformer's ``deform``;
- :class:`facegeom.viewer.playback.RetargetView` / :class:`facegeom.viewer.playback.AnimateView`: an
  actor's take beside the retargeted (and driven) character, play/pause, per-frame errors;
- :class:`facegeom.viewer.fit.FitView`: a landmark or mesh target beside every fitter's face,
  with the coefficients by blendshape name;
- :class:`facegeom.viewer.rig.RigView`: any blendshape rig posed with one slider per shape;
- :class:`facegeom.viewer.rig.TransferView`: the ICT template beside a character after
  ``facegeom transfer``'s registration, one set of sliders for both, the template drawn over the
  character, its 68 landmarks dragged, saved and used for a new registration;
- :class:`facegeom.viewer.character.CharacterView`: a Live Link take on the ICT face beside the
  user's character playing it through its rig, play/pause, scrubbing, the most active shapes;
- :class:`facegeom.viewer.character_markers.MarkerCharacterView`: the same beside any head driven
  through markers, the key frames' labels dragged with the mouse, refitted in a worker thread and saved.

Methods come from the plugin registry (:mod:`facegeom.registry`), cases from the
benchmark protocols (:mod:`facegeom.bench`). ``python -m facegeom.viewer.make_images``
regenerates the README images. Shared machinery is in :mod:`facegeom.viewer.app`, marker dragging in
:mod:`facegeom.viewer.dragging`.
"""
