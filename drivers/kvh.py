"""KVH 1750 / 1775 / DSP-1760 serial frames (docs/reference.md#kvh): Formats A, B, C and BIT.

Big-endian; CRC-32/MPEG-2 over every byte before the CRC, header included.
"""

from __future__ import annotations

from .formats import Field, FrameFormat, Multiplexed, register

_GYRO = Field(4, ">f4", 3)
_ACCEL = Field(16, ">f4", 3)

FORMAT_A = register(
    FrameFormat(
        name="kvh-a",
        label="Format A",
        family="KVH",
        header=b"\xfe\x81\xff\x55",
        length=36,
        check="crc32-mpeg2",
        fields={
            "gyro": _GYRO,
            "accel": _ACCEL,
            "status": Field(28, "u1"),
            "seq": Field(29, "u1"),
            "temperature": Field(30, ">i2"),
        },
        description="gyro, accel, status, sequence, int16 temperature",
    )
)

FORMAT_B = register(
    FrameFormat(
        name="kvh-b",
        label="Format B",
        family="KVH",
        header=b"\xfe\x81\xff\x56",
        length=40,
        check="crc32-mpeg2",
        fields={
            "gyro": _GYRO,
            "accel": _ACCEL,
            "timestamp": Field(28, ">u4"),
            "status": Field(32, "u1"),
            "seq": Field(33, "u1"),
            "temperature": Field(34, ">i2"),
        },
        timestamp_modulus=2**32,
        timestamp_scale_s=1e-6,
        description="as Format A plus a uint32 microsecond timestamp",
    )
)

FORMAT_C = register(
    FrameFormat(
        name="kvh-c",
        label="Format C",
        family="KVH",
        header=b"\xfe\x81\xff\x57",
        length=38,
        check="crc32-mpeg2",
        fields={
            "gyro": _GYRO,
            "accel": _ACCEL,
            "slot": Field(28, ">f4"),
            "status": Field(32, "u1"),
            "seq": Field(33, "u1"),
        },
        # The float at 28 is temperature when seq % 4 == 0, else magnetometer x, y, z (gauss).
        mux=Multiplexed(4, ("temperature", "mag_x", "mag_y", "mag_z")),
        description="as Format A with a float slot cycling temperature / magnetometer x, y, z",
    )
)

FORMAT_BIT = register(
    FrameFormat(
        name="kvh-bit",
        label="built-in-test message",
        family="KVH",
        header=b"\xfe\x81\x00\xaa",
        length=11,
        check="sum8",
        fields={"bit_data": Field(4, "u1", 6)},
        description="6 built-in-test bytes, checksum = sum of the preceding bytes mod 256",
    )
)
