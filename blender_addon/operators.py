""" "Segment Selected": the evaluated meshes go to the service on a worker thread while
Blender stays responsive (a modal operator polls the task on a timer; scripts and
background mode wait for the same task); labels come back as attributes and materials."""

from __future__ import annotations

import json
from array import array
from dataclasses import dataclass, field
from pathlib import Path
from typing import ClassVar

import bpy
import numpy as np

from . import apply_parts, colors, mesh_payload, service
from .properties import (
    DIGEST_KEY,
    EDITS_KEY,
    LABEL_NAMES_KEY,
    LABELER_KEY,
    MESH_ID_KEY,
    OPTIONS_KEY,
    PARTS_KEY,
    SERVER_KEY,
)
from .worker import WorkerTask


@dataclass
class ObjectRequest:
    """What one object sends, prepared on the main thread (bpy is not thread-safe)."""

    object_name: str
    payload: bytes
    digest: str
    polygons: int
    known_mesh_id: str | None
    #: The evaluated mesh (modifiers applied) when modifiers change the topology: the labels
    #: are written to a new object holding it. None: they go to the object's own mesh.
    evaluated_mesh: bpy.types.Mesh | None = None


@dataclass(kw_only=True)
class SegmentTask(WorkerTask):
    """Requests of several objects, run one after the other on a worker thread."""

    options: dict[str, object]
    requests: list[ObjectRequest]
    #: A labeller file's bytes and name: uploaded first (the service keeps it by its
    #: content id), then every object is labelled by it instead of segmented.
    labeler: tuple[bytes, str] | None = None
    outcomes: dict[str, service.Outcome] = field(default_factory=dict)

    def run_one(
        self, session: service.Session, request: ObjectRequest, report: service.Progress
    ) -> service.Outcome:
        """What the worker does for one object (a subclass may do more)."""
        return session.segment(
            request.payload,
            f"{request.object_name}.ply",
            self.options,
            report,
            mesh_id=request.known_mesh_id,
        )

    def work(self, session: service.Session) -> None:
        if self.labeler is not None:
            self.status = "uploading the labeller"
            stored = session.upload_labeler(*self.labeler)
            self.options = {**self.options, "labeler_id": stored["labeler_id"]}
        for index, request in enumerate(self.requests):

            def report(fraction: float, status: str, index: int = index) -> None:
                self.progress = (index + min(max(fraction, 0.0), 1.0)) / len(self.requests)
                self.status = f"{self.requests[index].object_name}: {status}"

            self.outcomes[request.object_name] = self.run_one(session, request, report)


def selected_meshes(context: bpy.types.Context) -> list[bpy.types.Object]:
    return [obj for obj in context.selected_objects if obj.type == "MESH"]


def prepare(context: bpy.types.Context, settings) -> SegmentTask:  # noqa: ANN001
    """The task for the selected mesh objects: evaluated meshes (modifiers applied) as PLY."""
    depsgraph = context.evaluated_depsgraph_get()
    server = settings.server_url.strip().rstrip("/")
    requests = []
    for obj in selected_meshes(context):
        evaluated_object = obj.evaluated_get(depsgraph)
        evaluated = evaluated_object.to_mesh()
        try:
            scale = tuple(obj.matrix_world.to_scale())
            arrays = mesh_payload.mesh_arrays(evaluated, scale)
            if arrays.polygon_count == 0:
                raise service.ServiceError(f"{obj.name!r} has no polygons to segment")
            same = arrays.same_topology(mesh_payload.mesh_arrays(obj.data))
            payload = mesh_payload.polygon_ply(arrays)
        finally:
            evaluated_object.to_mesh_clear()
        digest = mesh_payload.payload_digest(payload)
        known = obj.get(MESH_ID_KEY) if obj.get(DIGEST_KEY) == digest else None
        if obj.get(SERVER_KEY) != server:
            known = None
        requests.append(
            ObjectRequest(
                object_name=obj.name,
                payload=payload,
                digest=digest,
                polygons=arrays.polygon_count,
                known_mesh_id=known,
                evaluated_mesh=None
                if same
                else bpy.data.meshes.new_from_object(
                    evaluated_object, preserve_all_data_layers=True, depsgraph=depsgraph
                ),
            )
        )
    return SegmentTask(
        server_url=server,
        options=settings.options(),
        requests=requests,
        labeler=read_labeler(settings),
    )


def read_labeler(settings) -> tuple[bytes, str] | None:  # noqa: ANN001
    """The panel's labeller file (bytes, name), or None when none is set."""
    if not settings.labeler_file.strip():
        return None
    path = Path(bpy.path.abspath(settings.labeler_file))
    if not path.is_file():
        raise service.ServiceError(f"the labeller file {str(path)!r} does not exist")
    return path.read_bytes(), path.name


def target_object(context: bpy.types.Context, obj: bpy.types.Object, request: ObjectRequest):  # noqa: ANN201
    """Where the labels go: the object itself, or "<name> segmented" holding the evaluated
    mesh when modifiers change the topology (the source object is kept as it is, hidden)."""
    if request.evaluated_mesh is None:
        return obj
    name = f"{obj.name} segmented"
    target = bpy.data.objects.get(name)
    if target is None:
        target = bpy.data.objects.new(name, request.evaluated_mesh)
        for collection in obj.users_collection or [context.scene.collection]:
            collection.objects.link(target)
    else:
        old = target.data
        target.data = request.evaluated_mesh
        if old is not None and old.users == 0:
            bpy.data.meshes.remove(old)
    target.matrix_world = obj.matrix_world.copy()
    obj.hide_set(True)  # the result takes its place; the source stays, hidden
    return target


def apply(context: bpy.types.Context, task: SegmentTask, settings) -> list[str]:  # noqa: ANN001
    """Write every outcome back (main thread); returns one summary line per object."""
    lines = []
    for request in task.requests:
        obj = bpy.data.objects.get(request.object_name)
        outcome = task.outcomes.get(request.object_name)
        if obj is None or outcome is None:
            continue
        obj[MESH_ID_KEY] = outcome.mesh_id
        obj[DIGEST_KEY] = request.digest
        obj[SERVER_KEY] = task.server_url
        obj[PARTS_KEY] = outcome.part_count
        target = target_object(context, obj, request)
        # What a hand edit of the target needs: the mesh id and the options it ran with.
        target[MESH_ID_KEY] = outcome.mesh_id
        target[SERVER_KEY] = task.server_url
        target[OPTIONS_KEY] = json.dumps(task.options)
        if EDITS_KEY in target:  # a new segmentation starts a new edit
            del target[EDITS_KEY]
        labels = np.frombuffer(outcome.part_indices(), dtype=np.int32)
        part_colors = colors.part_colors(outcome.parts)  # the service's, linear
        names = [str(part["name"]) for part in outcome.parts] if outcome.named else None
        apply_parts.write_labels(target.data, labels, part_colors)
        if outcome.named:
            values = np.frombuffer(outcome.labels, dtype=np.int32)
            apply_parts.write_label_values(target.data, values, settings.label_attribute)
            pairs = zip(outcome.extra["label_values"], outcome.extra["label_names"], strict=True)
            target[LABEL_NAMES_KEY] = json.dumps({str(v): n for v, n in pairs})
            target[LABELER_KEY] = outcome.extra["labeler_id"]
        else:
            for key in (LABEL_NAMES_KEY, LABELER_KEY):
                if key in target:
                    del target[key]
        if settings.assign_materials or settings.split_parts:
            apply_parts.assign_materials(target.data, labels, part_colors, names)
        else:
            apply_parts.restore_materials(target.data)
        if settings.split_parts:
            apply_parts.split_parts(target, outcome.part_count, names)
        sent = "uploaded" if outcome.uploaded else "by mesh id"
        if names is not None:
            lines.append(f"{obj.name}: {', '.join(names)} ({sent})")
        else:
            lines.append(f"{obj.name}: {outcome.part_count} parts ({sent})")
    return lines


def _show(context: bpy.types.Context, task: WorkerTask | None) -> None:
    state = context.window_manager.neural_shdf_state
    state.running = task is not None and not task.done
    state.progress = task.progress if task else 0.0
    state.status = task.status if task else ""
    for window in context.window_manager.windows:
        for area in window.screen.areas:
            if area.type == "VIEW_3D":
                area.tag_redraw()


class ServiceTaskOperator:
    """What "Segment Selected" and the operators made like it share: a task on a worker
    thread, polled on a timer (Esc cancels), its outcomes written back on the main thread.
    A mixin (Blender cannot register a subclass of a registered operator)."""

    _task: WorkerTask | None = None
    _timer = None
    running_message = "A request to the service is running"

    @classmethod
    def poll(cls, context: bpy.types.Context) -> bool:
        if context.mode != "OBJECT":
            cls.poll_message_set("Switch to Object Mode")
            return False
        if context.window_manager.neural_shdf_state.running:
            cls.poll_message_set(cls.running_message)
            return False
        if not selected_meshes(context):
            cls.poll_message_set("Select one or more mesh objects")
            return False
        return True

    def make_task(self, context: bpy.types.Context) -> WorkerTask:
        """The worker's task for the selection (a subclass may make another kind)."""
        return prepare(context, context.scene.neural_shdf)

    def write_back(self, context: bpy.types.Context, task: WorkerTask) -> list[str]:
        """Write the task's outcomes to the objects (main thread); one line per object."""
        assert isinstance(task, SegmentTask)
        return apply(context, task, context.scene.neural_shdf)

    def _start(self, context: bpy.types.Context) -> bool:
        try:
            self._task = self.make_task(context)
        except (service.ServiceError, ValueError, OSError) as error:
            self.report({"ERROR"}, f"neural-shdf: {error}")
            return False
        self._task.start()
        _show(context, self._task)
        return True

    def _finish(self, context: bpy.types.Context) -> set[str]:
        task = self._task
        _show(context, None)
        if task is None:
            return {"CANCELLED"}
        if task.cancelled:
            self.report({"WARNING"}, "neural-shdf: cancelled")
            return {"CANCELLED"}
        if task.error:
            self.report({"ERROR"}, f"neural-shdf: {task.error}")
            return {"CANCELLED"}
        try:
            lines = self.write_back(context, task)
        except Exception as error:  # noqa: BLE001 - shown to the user, never a traceback
            self.report({"ERROR"}, f"neural-shdf: could not write the result back: {error}")
            return {"CANCELLED"}
        self.report({"INFO"}, f"neural-shdf: {'; '.join(lines)} in {task.seconds:.2f} s")
        return {"FINISHED"}

    def invoke(self, context: bpy.types.Context, event: bpy.types.Event) -> set[str]:
        """Interactive: start the worker, then poll it on a timer (Esc cancels)."""
        if not self._start(context):
            return {"CANCELLED"}
        window_manager = context.window_manager
        self._timer = window_manager.event_timer_add(0.1, window=context.window)
        window_manager.modal_handler_add(self)
        return {"RUNNING_MODAL"}

    def modal(self, context: bpy.types.Context, event: bpy.types.Event) -> set[str]:
        if self._task is None:
            return {"CANCELLED"}
        if event.type == "ESC":
            # Stop at once; the worker stops at its next step and its answer is dropped.
            self._task.cancel.set()
            self._task.cancelled = True
            return self._stop(context)
        if event.type != "TIMER":
            return {"PASS_THROUGH"}
        _show(context, self._task)
        context.workspace.status_text_set(
            f"neural-shdf: {self._task.status} ({self._task.progress:.0%}), Esc to cancel"
        )
        return self._stop(context) if self._task.done else {"PASS_THROUGH"}

    def _stop(self, context: bpy.types.Context) -> set[str]:
        context.window_manager.event_timer_remove(self._timer)
        context.workspace.status_text_set(None)
        return self._finish(context)

    def execute(self, context: bpy.types.Context) -> set[str]:
        """Scripts and background mode: the same worker, waited for here."""
        if not self._start(context):
            return {"CANCELLED"}
        assert self._task is not None
        self._task.wait()
        return self._finish(context)


class SegmentSelectedOperator(ServiceTaskOperator, bpy.types.Operator):
    """Split the selected meshes into parts with the neural-shdf service (named parts
    when the panel names a labeller)"""

    bl_idname = "neural_shdf.segment_selected"
    bl_label = "Segment Selected"
    bl_options = {"REGISTER", "UNDO"}
    running_message = "A segmentation is running"


@dataclass(kw_only=True)
class LearnTask(WorkerTask):
    """Train a labeller on the service from objects and their label attribute: upload
    each mesh, train (a job), download the labeller file (worker thread)."""

    thread_name: ClassVar[str] = "neural-shdf-learn"

    options: dict[str, object]
    meshes: list[tuple[str, bytes]]  # (object name, PLY of its polygons in order)
    labels: list[np.ndarray]  # per object, one label per polygon
    names: list[str] | None
    info: dict | None = None
    file: bytes = b""

    def work(self, session: service.Session) -> None:
        mesh_ids = []
        count = len(self.meshes)
        for index, (name, payload) in enumerate(self.meshes):

            def report(fraction: float, status: str, index: int = index, name: str = name):
                self.progress = 0.3 * (index + min(max(fraction, 0.0), 1.0)) / count
                self.status = f"{name}: {status}"

            mesh_ids.append(session.upload_mesh(payload, f"{name}.ply", report))

        def training(fraction: float, status: str) -> None:
            self.progress = 0.3 + 0.7 * min(max(fraction, 0.0), 1.0)
            self.status = status

        labels = array("i", np.concatenate(self.labels).astype(np.int32).tolist())
        self.info = session.train_labeler(mesh_ids, labels, self.names, self.options, training)
        self.file = session.labeler_file(self.info["labeler_id"])


def prepare_learning(context: bpy.types.Context, settings) -> LearnTask:  # noqa: ANN001
    """The selected objects' polygons (world scale, no modifiers: the attribute is on the
    object's own mesh) and their label attribute."""
    meshes, labels = [], []
    for obj in selected_meshes(context):
        values = apply_parts.read_label_values(obj.data, settings.label_attribute)
        scale = tuple(obj.matrix_world.to_scale())
        arrays = mesh_payload.mesh_arrays(obj.data, scale)
        if arrays.polygon_count == 0:
            raise service.ServiceError(f"{obj.name!r} has no polygons to learn from")
        meshes.append((obj.name, mesh_payload.polygon_ply(arrays)))
        labels.append(values)
    names = [n.strip() for n in settings.label_names.split(",")] if settings.label_names else None
    if names is not None and not all(names):
        raise ValueError(f"Label Names has an empty name: {settings.label_names!r}")
    options = {"method": settings.method} if settings.method != "default" else {}
    server = settings.server_url.strip().rstrip("/")
    return LearnTask(server_url=server, options=options, meshes=meshes, labels=labels, names=names)


class LearnFromSelectedOperator(ServiceTaskOperator, bpy.types.Operator):
    """Train a part labeller on the service from the selected objects' integer label
    attribute; save it and make it the panel's labeller"""

    bl_idname = "neural_shdf.learn_from_selected"
    bl_label = "Learn from Selected"
    bl_options = {"REGISTER"}
    running_message = "A request to the service is running"

    def make_task(self, context: bpy.types.Context) -> LearnTask:
        return prepare_learning(context, context.scene.neural_shdf)

    def write_back(self, context: bpy.types.Context, task: WorkerTask) -> list[str]:
        assert isinstance(task, LearnTask)
        settings = context.scene.neural_shdf
        path = Path(bpy.path.abspath(settings.learn_output or "//labeler.npz"))
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(task.file)
        settings.labeler_file = str(path)
        assert task.info is not None
        names = ", ".join(task.info["label_names"])
        return [f"labeller of {len(task.meshes)} objects ({names}) saved to {path}"]


CLASSES = (SegmentSelectedOperator, LearnFromSelectedOperator)
