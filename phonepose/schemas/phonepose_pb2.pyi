import datetime

from google.protobuf import timestamp_pb2 as _timestamp_pb2
from foxglove_schemas_protobuf import Pose_pb2 as _Pose_pb2
from foxglove_schemas_protobuf import Vector3_pb2 as _Vector3_pb2
from google.protobuf.internal import containers as _containers
from google.protobuf.internal import enum_type_wrapper as _enum_type_wrapper
from google.protobuf import descriptor as _descriptor
from google.protobuf import message as _message
from collections.abc import Iterable as _Iterable, Mapping as _Mapping
from typing import ClassVar as _ClassVar, Optional as _Optional, Union as _Union

DESCRIPTOR: _descriptor.FileDescriptor

class Imu(_message.Message):
    __slots__ = ("timestamp", "frame_id", "gyro_x", "gyro_y", "gyro_z", "accel_x", "accel_y", "accel_z")
    TIMESTAMP_FIELD_NUMBER: _ClassVar[int]
    FRAME_ID_FIELD_NUMBER: _ClassVar[int]
    GYRO_X_FIELD_NUMBER: _ClassVar[int]
    GYRO_Y_FIELD_NUMBER: _ClassVar[int]
    GYRO_Z_FIELD_NUMBER: _ClassVar[int]
    ACCEL_X_FIELD_NUMBER: _ClassVar[int]
    ACCEL_Y_FIELD_NUMBER: _ClassVar[int]
    ACCEL_Z_FIELD_NUMBER: _ClassVar[int]
    timestamp: _timestamp_pb2.Timestamp
    frame_id: str
    gyro_x: float
    gyro_y: float
    gyro_z: float
    accel_x: float
    accel_y: float
    accel_z: float
    def __init__(self, timestamp: _Optional[_Union[datetime.datetime, _timestamp_pb2.Timestamp, _Mapping]] = ..., frame_id: _Optional[str] = ..., gyro_x: _Optional[float] = ..., gyro_y: _Optional[float] = ..., gyro_z: _Optional[float] = ..., accel_x: _Optional[float] = ..., accel_y: _Optional[float] = ..., accel_z: _Optional[float] = ...) -> None: ...

class MarkerSpec(_message.Message):
    __slots__ = ("timestamp", "dictionary", "id", "size_m", "pose_in_body")
    TIMESTAMP_FIELD_NUMBER: _ClassVar[int]
    DICTIONARY_FIELD_NUMBER: _ClassVar[int]
    ID_FIELD_NUMBER: _ClassVar[int]
    SIZE_M_FIELD_NUMBER: _ClassVar[int]
    POSE_IN_BODY_FIELD_NUMBER: _ClassVar[int]
    timestamp: _timestamp_pb2.Timestamp
    dictionary: str
    id: int
    size_m: float
    pose_in_body: _Pose_pb2.Pose
    def __init__(self, timestamp: _Optional[_Union[datetime.datetime, _timestamp_pb2.Timestamp, _Mapping]] = ..., dictionary: _Optional[str] = ..., id: _Optional[int] = ..., size_m: _Optional[float] = ..., pose_in_body: _Optional[_Union[_Pose_pb2.Pose, _Mapping]] = ...) -> None: ...

class MarkerDetection(_message.Message):
    __slots__ = ("id", "corners_px", "pose_in_camera", "reprojection_error_px", "chosen_solution", "ambiguity_ratio", "controller_in_display_vio")
    ID_FIELD_NUMBER: _ClassVar[int]
    CORNERS_PX_FIELD_NUMBER: _ClassVar[int]
    POSE_IN_CAMERA_FIELD_NUMBER: _ClassVar[int]
    REPROJECTION_ERROR_PX_FIELD_NUMBER: _ClassVar[int]
    CHOSEN_SOLUTION_FIELD_NUMBER: _ClassVar[int]
    AMBIGUITY_RATIO_FIELD_NUMBER: _ClassVar[int]
    CONTROLLER_IN_DISPLAY_VIO_FIELD_NUMBER: _ClassVar[int]
    id: int
    corners_px: _containers.RepeatedScalarFieldContainer[float]
    pose_in_camera: _Pose_pb2.Pose
    reprojection_error_px: float
    chosen_solution: int
    ambiguity_ratio: float
    controller_in_display_vio: _Pose_pb2.Pose
    def __init__(self, id: _Optional[int] = ..., corners_px: _Optional[_Iterable[float]] = ..., pose_in_camera: _Optional[_Union[_Pose_pb2.Pose, _Mapping]] = ..., reprojection_error_px: _Optional[float] = ..., chosen_solution: _Optional[int] = ..., ambiguity_ratio: _Optional[float] = ..., controller_in_display_vio: _Optional[_Union[_Pose_pb2.Pose, _Mapping]] = ...) -> None: ...

class MarkerDetections(_message.Message):
    __slots__ = ("timestamp", "frame_id", "detections")
    TIMESTAMP_FIELD_NUMBER: _ClassVar[int]
    FRAME_ID_FIELD_NUMBER: _ClassVar[int]
    DETECTIONS_FIELD_NUMBER: _ClassVar[int]
    timestamp: _timestamp_pb2.Timestamp
    frame_id: str
    detections: _containers.RepeatedCompositeFieldContainer[MarkerDetection]
    def __init__(self, timestamp: _Optional[_Union[datetime.datetime, _timestamp_pb2.Timestamp, _Mapping]] = ..., frame_id: _Optional[str] = ..., detections: _Optional[_Iterable[_Union[MarkerDetection, _Mapping]]] = ...) -> None: ...

class CalibrationEvent(_message.Message):
    __slots__ = ("timestamp", "kind", "frame_id", "pose_fix_vio", "pose_align_vio", "fix_timestamp")
    class Kind(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
        __slots__ = ()
        KIND_UNSPECIFIED: _ClassVar[CalibrationEvent.Kind]
        CM1: _ClassVar[CalibrationEvent.Kind]
        CM2: _ClassVar[CalibrationEvent.Kind]
    KIND_UNSPECIFIED: CalibrationEvent.Kind
    CM1: CalibrationEvent.Kind
    CM2: CalibrationEvent.Kind
    TIMESTAMP_FIELD_NUMBER: _ClassVar[int]
    KIND_FIELD_NUMBER: _ClassVar[int]
    FRAME_ID_FIELD_NUMBER: _ClassVar[int]
    POSE_FIX_VIO_FIELD_NUMBER: _ClassVar[int]
    POSE_ALIGN_VIO_FIELD_NUMBER: _ClassVar[int]
    FIX_TIMESTAMP_FIELD_NUMBER: _ClassVar[int]
    timestamp: _timestamp_pb2.Timestamp
    kind: CalibrationEvent.Kind
    frame_id: str
    pose_fix_vio: _Pose_pb2.Pose
    pose_align_vio: _Pose_pb2.Pose
    fix_timestamp: _timestamp_pb2.Timestamp
    def __init__(self, timestamp: _Optional[_Union[datetime.datetime, _timestamp_pb2.Timestamp, _Mapping]] = ..., kind: _Optional[_Union[CalibrationEvent.Kind, str]] = ..., frame_id: _Optional[str] = ..., pose_fix_vio: _Optional[_Union[_Pose_pb2.Pose, _Mapping]] = ..., pose_align_vio: _Optional[_Union[_Pose_pb2.Pose, _Mapping]] = ..., fix_timestamp: _Optional[_Union[datetime.datetime, _timestamp_pb2.Timestamp, _Mapping]] = ...) -> None: ...

class Target(_message.Message):
    __slots__ = ("index", "pose", "inside_view", "hold_start", "hold_end")
    INDEX_FIELD_NUMBER: _ClassVar[int]
    POSE_FIELD_NUMBER: _ClassVar[int]
    INSIDE_VIEW_FIELD_NUMBER: _ClassVar[int]
    HOLD_START_FIELD_NUMBER: _ClassVar[int]
    HOLD_END_FIELD_NUMBER: _ClassVar[int]
    index: int
    pose: _Pose_pb2.Pose
    inside_view: bool
    hold_start: _timestamp_pb2.Timestamp
    hold_end: _timestamp_pb2.Timestamp
    def __init__(self, index: _Optional[int] = ..., pose: _Optional[_Union[_Pose_pb2.Pose, _Mapping]] = ..., inside_view: _Optional[bool] = ..., hold_start: _Optional[_Union[datetime.datetime, _timestamp_pb2.Timestamp, _Mapping]] = ..., hold_end: _Optional[_Union[datetime.datetime, _timestamp_pb2.Timestamp, _Mapping]] = ...) -> None: ...

class Targets(_message.Message):
    __slots__ = ("timestamp", "frame_id", "cube_size_m", "select_radius_m", "targets")
    TIMESTAMP_FIELD_NUMBER: _ClassVar[int]
    FRAME_ID_FIELD_NUMBER: _ClassVar[int]
    CUBE_SIZE_M_FIELD_NUMBER: _ClassVar[int]
    SELECT_RADIUS_M_FIELD_NUMBER: _ClassVar[int]
    TARGETS_FIELD_NUMBER: _ClassVar[int]
    timestamp: _timestamp_pb2.Timestamp
    frame_id: str
    cube_size_m: float
    select_radius_m: float
    targets: _containers.RepeatedCompositeFieldContainer[Target]
    def __init__(self, timestamp: _Optional[_Union[datetime.datetime, _timestamp_pb2.Timestamp, _Mapping]] = ..., frame_id: _Optional[str] = ..., cube_size_m: _Optional[float] = ..., select_radius_m: _Optional[float] = ..., targets: _Optional[_Iterable[_Union[Target, _Mapping]]] = ...) -> None: ...

class PathSpec(_message.Message):
    __slots__ = ("timestamp", "frame_id", "name", "trial", "waypoints", "closed")
    TIMESTAMP_FIELD_NUMBER: _ClassVar[int]
    FRAME_ID_FIELD_NUMBER: _ClassVar[int]
    NAME_FIELD_NUMBER: _ClassVar[int]
    TRIAL_FIELD_NUMBER: _ClassVar[int]
    WAYPOINTS_FIELD_NUMBER: _ClassVar[int]
    CLOSED_FIELD_NUMBER: _ClassVar[int]
    timestamp: _timestamp_pb2.Timestamp
    frame_id: str
    name: str
    trial: int
    waypoints: _containers.RepeatedCompositeFieldContainer[_Vector3_pb2.Vector3]
    closed: bool
    def __init__(self, timestamp: _Optional[_Union[datetime.datetime, _timestamp_pb2.Timestamp, _Mapping]] = ..., frame_id: _Optional[str] = ..., name: _Optional[str] = ..., trial: _Optional[int] = ..., waypoints: _Optional[_Iterable[_Union[_Vector3_pb2.Vector3, _Mapping]]] = ..., closed: _Optional[bool] = ...) -> None: ...

class SessionInfo(_message.Message):
    __slots__ = ("timestamp", "source", "scenario", "path", "trial", "seed", "phonepose_version", "config_toml", "description", "task_start", "task_end", "ground_truth_source")
    TIMESTAMP_FIELD_NUMBER: _ClassVar[int]
    SOURCE_FIELD_NUMBER: _ClassVar[int]
    SCENARIO_FIELD_NUMBER: _ClassVar[int]
    PATH_FIELD_NUMBER: _ClassVar[int]
    TRIAL_FIELD_NUMBER: _ClassVar[int]
    SEED_FIELD_NUMBER: _ClassVar[int]
    PHONEPOSE_VERSION_FIELD_NUMBER: _ClassVar[int]
    CONFIG_TOML_FIELD_NUMBER: _ClassVar[int]
    DESCRIPTION_FIELD_NUMBER: _ClassVar[int]
    TASK_START_FIELD_NUMBER: _ClassVar[int]
    TASK_END_FIELD_NUMBER: _ClassVar[int]
    GROUND_TRUTH_SOURCE_FIELD_NUMBER: _ClassVar[int]
    timestamp: _timestamp_pb2.Timestamp
    source: str
    scenario: str
    path: str
    trial: int
    seed: int
    phonepose_version: str
    config_toml: str
    description: str
    task_start: _timestamp_pb2.Timestamp
    task_end: _timestamp_pb2.Timestamp
    ground_truth_source: str
    def __init__(self, timestamp: _Optional[_Union[datetime.datetime, _timestamp_pb2.Timestamp, _Mapping]] = ..., source: _Optional[str] = ..., scenario: _Optional[str] = ..., path: _Optional[str] = ..., trial: _Optional[int] = ..., seed: _Optional[int] = ..., phonepose_version: _Optional[str] = ..., config_toml: _Optional[str] = ..., description: _Optional[str] = ..., task_start: _Optional[_Union[datetime.datetime, _timestamp_pb2.Timestamp, _Mapping]] = ..., task_end: _Optional[_Union[datetime.datetime, _timestamp_pb2.Timestamp, _Mapping]] = ..., ground_truth_source: _Optional[str] = ...) -> None: ...
