"""emScon TPI enumerations (values from Leica's ES_C_API_Def.h, TPI/SDK V3.6).

Every enum travels as a signed little-endian int32. Decoders keep unknown values as
plain ints (a newer server may send values this table does not know); use
:func:`enum_name` to print any of them. docs/emscon.md's enum table is generated from
these classes and their docstrings (``python -m drivers.emscon.enum_table --markdown``; a test
compares), so a value or a name is written here only.
"""
from __future__ import annotations

from enum import IntEnum


class ES_DataType(IntEnum):
    """Packet type, the second int32 of every packet"""
    Command = 0
    Error = 1
    SingleMeasResult = 2
    MultiMeasResult = 3
    StationaryProbeMeasResult = 4
    ContinuousProbeMeasResult = 5
    NivelResult = 6
    ReflectorPosResult = 7
    SystemStatusChange = 8
    SingleMeasResult2 = 9
    MultiMeasResult2 = 10
    ProbePosResult = 11


class ES_Command(IntEnum):
    """Command of a request, its answer and an error packet; `tracker.event` `command_name`"""
    ExitApplication = 0
    GetSystemStatus = 1
    GetTrackerStatus = 2
    SetUnits = 5
    GetUnits = 6
    Initialize = 7
    ReleaseMotors = 8
    Park = 10
    SwitchLaser = 11
    SetStationOrientationParams = 12
    GetStationOrientationParams = 13
    SetTransformationParams = 14
    GetTransformationParams = 15
    SetEnvironmentParams = 20
    GetEnvironmentParams = 21
    SetRefractionParams = 22
    GetRefractionParams = 23
    SetMeasurementMode = 24
    GetMeasurementMode = 25
    SetCoordinateSystemType = 26
    GetCoordinateSystemType = 27
    SetStationaryModeParams = 28
    GetStationaryModeParams = 29
    SetContinuousTimeModeParams = 30
    GetContinuousTimeModeParams = 31
    SetContinuousDistanceModeParams = 32
    GetContinuousDistanceModeParams = 33
    SetReflector = 40
    GetReflector = 41
    GetReflectors = 42
    SetSearchParams = 43
    GetSearchParams = 44
    SetSystemSettings = 47
    GetSystemSettings = 48
    StartMeasurement = 49
    StartNivelMeasurement = 51
    StopMeasurement = 52
    ChangeFace = 53
    GoBirdBath = 54
    GoPosition = 55
    GoPositionHVD = 56
    PositionRelativeHV = 57
    PointLaser = 58
    PointLaserHVD = 59
    MoveHV = 60
    GoLastMeasuredPoint = 62
    FindReflector = 63
    LookForTarget = 65
    GetDirection = 66
    SetStatisticMode = 80
    GetStatisticMode = 81
    GoBirdBath2 = 95
    GetFace = 98
    SetLongSystemParameter = 120
    GetLongSystemParameter = 121
    GetMeasurementStatusInfo = 122
    SetDoubleSystemParameter = 125
    GetDoubleSystemParameter = 126
    ClearCommandQueue = 130
    GetADMInfo2 = 131
    GetTrackerInfo = 132
    RestoreStartupConditions = 134
    GoAndMeasure = 135
    GetAT4xxInfo = 140
    GetSystemSoftwareVersion = 142


class ES_ResultStatus(IntEnum):
    """A command's result; a refused command is the bus error `tracker_<name>`,
    also `tracker.event` `status_name`"""
    AllOK = 0
    ServerBusy = 1
    NotImplemented = 2
    WrongParameter = 3
    WrongParameter1 = 4
    WrongParameter2 = 5
    WrongParameter3 = 6
    WrongParameter4 = 7
    WrongParameter5 = 8
    WrongParameter6 = 9
    WrongParameter7 = 10
    Parameter1OutOfRangeOK = 11
    Parameter1OutOfRangeNOK = 12
    Parameter2OutOfRangeOK = 13
    Parameter2OutOfRangeNOK = 14
    Parameter3OutOfRangeOK = 15
    Parameter3OutOfRangeNOK = 16
    Parameter4OutOfRangeOK = 17
    Parameter4OutOfRangeNOK = 18
    Parameter5OutOfRangeOK = 19
    Parameter5OutOfRangeNOK = 20
    Parameter6OutOfRangeOK = 21
    Parameter6OutOfRangeNOK = 22
    WrongCurrentReflector = 23
    NoCircleCenterFound = 24
    NoSphereCenterFound = 25
    NoTPFound = 26
    NoWeathermonitorFound = 27
    NoLastMeasuredPoint = 28
    NoVideoCamera = 29
    NoAdm = 30
    NoNivel = 31
    WrongTPFirmware = 32
    DataBaseNotFound = 33
    LicenseExpired = 34
    UsageConflict = 35
    Unknown = 36
    NoDistanceSet = 37
    NoTrackerConnected = 38
    TrackerNotInitialized = 39
    ModuleNotStarted = 40
    ModuleTimedOut = 41
    NotInCameraPosition = 44
    TPExternalControl = 46
    WrongParameter8 = 47
    WrongParameter9 = 48
    WrongParameter10 = 49
    WrongParameter11 = 50
    WrongParameter12 = 51
    WrongParameter13 = 52
    WrongParameter14 = 53
    WrongParameter15 = 54
    WrongParameter16 = 55
    NoSuchCompensation = 56
    MeteoDataOutOfRange = 57
    InternalProcessActive = 59
    NoDataToImport = 90
    NoTemperatureFromWM = 94
    NoPressureFromWM = 95
    NoHumidityFromWM = 96
    InvalidInputData = 98
    NoValidADMCompensation = 10002
    PressureSensorProblem = 10003
    MeasurementStatusNotReady = 10004
    AIFMStartUpBusy = 10005
    InvalidTipAdapter = 10006
    NoAtr = 10007
    NoOVC = 10008
    NoStationaryResult = 10009
    SensorNotLeveled = 10010
    MultiConnectionsNotAllowed = 10011
    SensorNotWarmedUp = 10012
    SensorNotStable = 10013
    SystemNotReadyForMeasurement = 10014
    CommunicationWithSensorFailed = 10015
    No_Sensor_Battery = 10016
    CompensatorNotAllowed = 10017
    WarmedUpStateReached = 10018
    NotLeveledForInitialization = 10019
    ADMHardwareProblem = 10020
    ATRHardwareProblem = 10021


class ES_MeasMode(IntEnum):
    """Measurement mode (SetMeasurementMode)"""
    Stationary = 0
    ContinuousTime = 1
    ContinuousDistance = 2
    Grid = 3
    SphereCenter = 4
    CircleCenter = 5


class ES_TrackerStatus(IntEnum):
    """Tracker state (GetTrackerStatus); `tracker.status` `tracker_status`"""
    NotReady = 0
    Busy = 1
    Ready = 2
    Status6DInvalid = 3


class ES_SystemStatusChange(IntEnum):
    """What an unsolicited status-change packet reports; `tracker.event` `change_name`"""
    DistanceSet = 0
    LaserWarmedUp = 1
    EnvironmentParamsChanged = 2
    RefractionParamsChanged = 3
    SearchParamsChanged = 4
    AdmParamsChanged = 5
    UnitsChanged = 6
    ReflectorChanged = 7
    SystemSettingsChanged = 8
    TemperatureRangeChanged = 9
    CameraParamsChanged = 10
    CompensationChanged = 11
    CoordinateSystemTypeChanged = 12
    BoxRegionParamsChanged = 13
    SphereRegionParamsChanged = 14
    StationOrientationParamsChanged = 15
    TransformationParamsChanged = 16
    MeasurementModeChanged = 17
    StationaryModeParamsChanged = 18
    ContinuousTimeModeParamsChanged = 19
    ContinuousDistanceModeParamsChanged = 20
    GridModeParamsChanged = 21
    CircleCenterModeParamsChanged = 22
    SphereCenterModeParamsChanged = 23
    StatisticModeChanged = 24
    MeasStatus_NotReady = 25
    MeasStatus_Busy = 26
    MeasStatus_Ready = 27
    MeasurementCountReached = 28
    TriggerSourceChanged = 29
    IsFace1 = 30
    IsFace2 = 31
    LaserReachingLimit = 145
    LaserNotStabilized = 146
    InitializationStatusChanged = 151
    TiltSensorStatusChanged = 152
    SensorDetected = 850
    SensorDisconnected = 851
    TPConnectionClosing = 997
    ServerClosing = 998
    ServerStarted = 999


class ES_LengthUnit(IntEnum):
    """Length unit (SetUnits; the driver sets Millimeter)"""
    Meter = 0
    Millimeter = 1
    Micron = 2
    Foot = 3
    Yard = 4
    Inch = 5


class ES_AngleUnit(IntEnum):
    """Angle unit (SetUnits; the driver sets Degree)"""
    Radian = 0
    Degree = 1
    Gon = 2


class ES_TemperatureUnit(IntEnum):
    """Temperature unit (SetUnits; the driver sets Celsius)"""
    Celsius = 0
    Fahrenheit = 1


class ES_PressureUnit(IntEnum):
    """Pressure unit (SetUnits; the driver sets Mbar)"""
    Mbar = 0
    HPascal = 1
    KPascal = 2
    MmHg = 3
    Psi = 4
    InH2O = 5
    InHg = 6


class ES_HumidityUnit(IntEnum):
    """Humidity unit (SetUnits)"""
    RH = 0


class ES_CoordinateSystemType(IntEnum):
    """Coordinate system handedness and axes (the driver sets RHR)"""
    RHR = 0
    LHRX = 1
    LHRY = 2
    LHRZ = 3
    CCW = 4
    CCC = 5
    SCW = 6
    SCC = 7


class ES_TrackerProcessorStatus(IntEnum):
    """GetSystemStatus: the tracker processor (Initialize runs unless Initialized)"""
    NoTPFound = 0
    TPFound = 1
    NBOpen = 2
    Booted = 3
    CompensationSet = 4
    Initialized = 5


class ES_LaserProcessorStatus(IntEnum):
    """GetSystemStatus: the laser"""
    LCPCommFailed = 0
    LCPNotAvail = 1
    LaserHeatingUp = 2
    LaserReady = 3
    UnableToStabilize = 4
    LaserOff = 5


class ES_ADMStatus(IntEnum):
    """GetSystemStatus: the absolute distance meter"""
    NoADM = 0
    ADMCommFailed = 1
    ADMReady = 2
    ADMBusy = 3
    HWError = 4
    SecurityLockActive = 5
    NotCompensated = 6


class ES_WeatherMonitorStatus(IntEnum):
    """GetSystemStatus: the weather monitor"""
    NotConnected = 0
    ReadOnly = 1
    ReadAndCalculateRefractions = 2


class ES_MeasurementStatus(IntEnum):
    """Status of one continuous measurement record"""
    AllOK = 0
    SpeedWarning = 1
    SpeedExeeded = 2
    PrismError = 3
    TriggerTimeViolation = 4


class ES_TargetType(IntEnum):
    """Reflector type (GetReflectors)"""
    Unknown = 0
    CornerCube = 1
    CatsEye = 2
    GlassPrism = 3
    RFIPrism = 4
    RRR15 = 5
    RRR05 = 6
    BRR15 = 7
    BRR05 = 8
    TBR05 = 9


class ES_LTSensorType(IntEnum):
    """Tracker model (GetTrackerInfo); `tracker.status` `info.tracker_type`"""
    AT901_B = 13
    AT901_MR = 14
    AT901_LR = 15
    AT401 = 70


class ES_SystemParameter(IntEnum):
    """Long system parameter id (Set/GetLongSystemParameter); TcpDataPacketRate is 3-10 packets/s"""
    TcpCommandQueueSize = 200
    TcpDataPacketRate = 400


class ES_RegionType(IntEnum):
    """Measurement region shape"""
    Sphere = 0
    Box = 1


def enum_name(enum_cls: type[IntEnum], value: int) -> str:
    """Name of ``value`` in ``enum_cls``, or ``"<Enum>#<value>"`` when unknown."""
    try:
        return enum_cls(value).name
    except ValueError:
        return f"{enum_cls.__name__}#{int(value)}"


def as_enum(enum_cls: type[IntEnum], value: int) -> int:
    """``enum_cls(value)`` when known, else the plain int (decoders never fail on it)."""
    try:
        return enum_cls(value)
    except ValueError:
        return int(value)

