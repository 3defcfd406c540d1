from chronos_bridge.proto import vector3_pb2 as _vector3_pb2
from google.protobuf.internal import containers as _containers
from google.protobuf import descriptor as _descriptor
from google.protobuf import message as _message
from collections.abc import Iterable as _Iterable, Mapping as _Mapping
from typing import ClassVar as _ClassVar, Optional as _Optional, Union as _Union

DESCRIPTOR: _descriptor.FileDescriptor

class Packet(_message.Message):
    __slots__ = ("ping", "control_input", "car_state", "reference", "timestamp")
    PING_FIELD_NUMBER: _ClassVar[int]
    CONTROL_INPUT_FIELD_NUMBER: _ClassVar[int]
    CAR_STATE_FIELD_NUMBER: _ClassVar[int]
    REFERENCE_FIELD_NUMBER: _ClassVar[int]
    TIMESTAMP_FIELD_NUMBER: _ClassVar[int]
    ping: Ping
    control_input: SingleControlInput
    car_state: CarState
    reference: CarReference
    timestamp: int
    def __init__(self, ping: _Optional[_Union[Ping, _Mapping]] = ..., control_input: _Optional[_Union[SingleControlInput, _Mapping]] = ..., car_state: _Optional[_Union[CarState, _Mapping]] = ..., reference: _Optional[_Union[CarReference, _Mapping]] = ..., timestamp: _Optional[int] = ...) -> None: ...

class Ping(_message.Message):
    __slots__ = ("should_bounce",)
    SHOULD_BOUNCE_FIELD_NUMBER: _ClassVar[int]
    should_bounce: bool
    def __init__(self, should_bounce: _Optional[bool] = ...) -> None: ...

class CarReference(_message.Message):
    __slots__ = ("throttle", "longitudinal_velocity", "voltage", "angle")
    THROTTLE_FIELD_NUMBER: _ClassVar[int]
    LONGITUDINAL_VELOCITY_FIELD_NUMBER: _ClassVar[int]
    VOLTAGE_FIELD_NUMBER: _ClassVar[int]
    ANGLE_FIELD_NUMBER: _ClassVar[int]
    throttle: float
    longitudinal_velocity: float
    voltage: int
    angle: float
    def __init__(self, throttle: _Optional[float] = ..., longitudinal_velocity: _Optional[float] = ..., voltage: _Optional[int] = ..., angle: _Optional[float] = ...) -> None: ...

class SingleControlInput(_message.Message):
    __slots__ = ("torque_ref", "steer_ref", "steer_input")
    TORQUE_REF_FIELD_NUMBER: _ClassVar[int]
    STEER_REF_FIELD_NUMBER: _ClassVar[int]
    STEER_INPUT_FIELD_NUMBER: _ClassVar[int]
    torque_ref: float
    steer_ref: float
    steer_input: SteerInput
    def __init__(self, torque_ref: _Optional[float] = ..., steer_ref: _Optional[float] = ..., steer_input: _Optional[_Union[SteerInput, _Mapping]] = ...) -> None: ...

class SteerInput(_message.Message):
    __slots__ = ("steer_angle", "steer_voltage")
    STEER_ANGLE_FIELD_NUMBER: _ClassVar[int]
    STEER_VOLTAGE_FIELD_NUMBER: _ClassVar[int]
    steer_angle: float
    steer_voltage: int
    def __init__(self, steer_angle: _Optional[float] = ..., steer_voltage: _Optional[int] = ...) -> None: ...

class CarState(_message.Message):
    __slots__ = ("current_reference", "drive_motor_input", "steer_motor_input", "imu_data", "steer_data", "wheel_speed_data", "battery_state", "lighthouse_data", "lighthouse_sweeps", "longitudinal_velocity")
    CURRENT_REFERENCE_FIELD_NUMBER: _ClassVar[int]
    DRIVE_MOTOR_INPUT_FIELD_NUMBER: _ClassVar[int]
    STEER_MOTOR_INPUT_FIELD_NUMBER: _ClassVar[int]
    IMU_DATA_FIELD_NUMBER: _ClassVar[int]
    STEER_DATA_FIELD_NUMBER: _ClassVar[int]
    WHEEL_SPEED_DATA_FIELD_NUMBER: _ClassVar[int]
    BATTERY_STATE_FIELD_NUMBER: _ClassVar[int]
    LIGHTHOUSE_DATA_FIELD_NUMBER: _ClassVar[int]
    LIGHTHOUSE_SWEEPS_FIELD_NUMBER: _ClassVar[int]
    LONGITUDINAL_VELOCITY_FIELD_NUMBER: _ClassVar[int]
    current_reference: SingleControlInput
    drive_motor_input: MotorInput
    steer_motor_input: MotorInput
    imu_data: IMUMeasurement
    steer_data: SteeringPositionMeasurement
    wheel_speed_data: WheelSpeedMeasurement
    battery_state: BatteryState
    lighthouse_data: _containers.RepeatedCompositeFieldContainer[LighthouseFrame]
    lighthouse_sweeps: _containers.RepeatedCompositeFieldContainer[LighthouseSweep]
    longitudinal_velocity: float
    def __init__(self, current_reference: _Optional[_Union[SingleControlInput, _Mapping]] = ..., drive_motor_input: _Optional[_Union[MotorInput, _Mapping]] = ..., steer_motor_input: _Optional[_Union[MotorInput, _Mapping]] = ..., imu_data: _Optional[_Union[IMUMeasurement, _Mapping]] = ..., steer_data: _Optional[_Union[SteeringPositionMeasurement, _Mapping]] = ..., wheel_speed_data: _Optional[_Union[WheelSpeedMeasurement, _Mapping]] = ..., battery_state: _Optional[_Union[BatteryState, _Mapping]] = ..., lighthouse_data: _Optional[_Iterable[_Union[LighthouseFrame, _Mapping]]] = ..., lighthouse_sweeps: _Optional[_Iterable[_Union[LighthouseSweep, _Mapping]]] = ..., longitudinal_velocity: _Optional[float] = ...) -> None: ...

class MotorInput(_message.Message):
    __slots__ = ("power",)
    POWER_FIELD_NUMBER: _ClassVar[int]
    power: float
    def __init__(self, power: _Optional[float] = ...) -> None: ...

class IMUMeasurement(_message.Message):
    __slots__ = ("linear_acceleration", "angular_velocity")
    LINEAR_ACCELERATION_FIELD_NUMBER: _ClassVar[int]
    ANGULAR_VELOCITY_FIELD_NUMBER: _ClassVar[int]
    linear_acceleration: _vector3_pb2.Vector3
    angular_velocity: _vector3_pb2.Vector3
    def __init__(self, linear_acceleration: _Optional[_Union[_vector3_pb2.Vector3, _Mapping]] = ..., angular_velocity: _Optional[_Union[_vector3_pb2.Vector3, _Mapping]] = ...) -> None: ...

class SteeringPositionMeasurement(_message.Message):
    __slots__ = ("steer_rad", "adc_meas", "adc_limits", "amplitude")
    STEER_RAD_FIELD_NUMBER: _ClassVar[int]
    ADC_MEAS_FIELD_NUMBER: _ClassVar[int]
    ADC_LIMITS_FIELD_NUMBER: _ClassVar[int]
    AMPLITUDE_FIELD_NUMBER: _ClassVar[int]
    steer_rad: float
    adc_meas: int
    adc_limits: int
    amplitude: float
    def __init__(self, steer_rad: _Optional[float] = ..., adc_meas: _Optional[int] = ..., adc_limits: _Optional[int] = ..., amplitude: _Optional[float] = ...) -> None: ...

class WheelSpeedMeasurement(_message.Message):
    __slots__ = ("front_right", "front_left", "rear_right", "rear_left")
    FRONT_RIGHT_FIELD_NUMBER: _ClassVar[int]
    FRONT_LEFT_FIELD_NUMBER: _ClassVar[int]
    REAR_RIGHT_FIELD_NUMBER: _ClassVar[int]
    REAR_LEFT_FIELD_NUMBER: _ClassVar[int]
    front_right: float
    front_left: float
    rear_right: float
    rear_left: float
    def __init__(self, front_right: _Optional[float] = ..., front_left: _Optional[float] = ..., rear_right: _Optional[float] = ..., rear_left: _Optional[float] = ...) -> None: ...

class BatteryState(_message.Message):
    __slots__ = ("voltage", "current")
    VOLTAGE_FIELD_NUMBER: _ClassVar[int]
    CURRENT_FIELD_NUMBER: _ClassVar[int]
    voltage: float
    current: float
    def __init__(self, voltage: _Optional[float] = ..., current: _Optional[float] = ...) -> None: ...

class LighthouseFrame(_message.Message):
    __slots__ = ("sensor_id", "polynomial", "pulse_width", "sync_offset", "beam_word", "timestamp")
    SENSOR_ID_FIELD_NUMBER: _ClassVar[int]
    POLYNOMIAL_FIELD_NUMBER: _ClassVar[int]
    PULSE_WIDTH_FIELD_NUMBER: _ClassVar[int]
    SYNC_OFFSET_FIELD_NUMBER: _ClassVar[int]
    BEAM_WORD_FIELD_NUMBER: _ClassVar[int]
    TIMESTAMP_FIELD_NUMBER: _ClassVar[int]
    sensor_id: int
    polynomial: int
    pulse_width: int
    sync_offset: int
    beam_word: int
    timestamp: int
    def __init__(self, sensor_id: _Optional[int] = ..., polynomial: _Optional[int] = ..., pulse_width: _Optional[int] = ..., sync_offset: _Optional[int] = ..., beam_word: _Optional[int] = ..., timestamp: _Optional[int] = ...) -> None: ...

class LighthouseSweep(_message.Message):
    __slots__ = ("angle_0", "angle_1", "angle_2", "angle_3", "polynomial", "first_timestamp", "sync_timestamp")
    ANGLE_0_FIELD_NUMBER: _ClassVar[int]
    ANGLE_1_FIELD_NUMBER: _ClassVar[int]
    ANGLE_2_FIELD_NUMBER: _ClassVar[int]
    ANGLE_3_FIELD_NUMBER: _ClassVar[int]
    POLYNOMIAL_FIELD_NUMBER: _ClassVar[int]
    FIRST_TIMESTAMP_FIELD_NUMBER: _ClassVar[int]
    SYNC_TIMESTAMP_FIELD_NUMBER: _ClassVar[int]
    angle_0: float
    angle_1: float
    angle_2: float
    angle_3: float
    polynomial: int
    first_timestamp: int
    sync_timestamp: int
    def __init__(self, angle_0: _Optional[float] = ..., angle_1: _Optional[float] = ..., angle_2: _Optional[float] = ..., angle_3: _Optional[float] = ..., polynomial: _Optional[int] = ..., first_timestamp: _Optional[int] = ..., sync_timestamp: _Optional[int] = ...) -> None: ...
