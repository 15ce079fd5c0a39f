"""NMEA: the simulated receiver's sentences parse back (with pynmea2) into the same fix."""
import math

import pynmea2
import pytest

from quadrivio_description.site import load_site
from quadrivio_drivers.nmea import (COVARIANCE_APPROXIMATED, COVARIANCE_DIAGONAL_KNOWN, GBAS_FIX, NO_FIX, SBAS_FIX,
                                    Fix, NmeaFixParser, Velocity)
from quadrivio_sim.nmea_out import NmeaEncoder
from quadrivio_sim.noise import FIX, GpsReading

SITE = load_site()
FRAME = SITE.local_frame()
ENC = NmeaEncoder(FRAME, SITE.utc_epoch, geoid_separation=47.0)


def reading(t, enu, status=GBAS_FIX, var=(0.0009, 0.0016, 0.0036), vel=(1.0, 2.0, 0.0)):
    return GpsReading(t, status, enu, vel, var, False, 14, 0.7)


def parse_all(lines, parser=None):
    parser = parser or NmeaFixParser()
    out = []
    for k, line in enumerate(lines):
        out += parser.feed_line(line, 100.0 + k)
    return out, parser


@pytest.mark.parametrize("enu", [(0.0, 0.0, 0.0), (12.345, -67.891, 1.5), (-1500.25, 2200.75, -3.0)])
def test_round_trip_position_and_covariance(enu):
    out, parser = parse_all(ENC.encode(reading(3.2, enu)))
    fixes = [o for o in out if isinstance(o, Fix)]
    assert len(fixes) == 1
    f = fixes[0]
    lat, lon, alt = FRAME.enu_to_lla(*enu)
    assert (f.latitude, f.longitude) == pytest.approx((lat, lon), abs=1e-9)  # 0.1 mm
    assert f.altitude == pytest.approx(alt, abs=1e-3)
    assert f.status == GBAS_FIX
    assert f.covariance_type == COVARIANCE_DIAGONAL_KNOWN
    assert (f.covariance[0], f.covariance[4], f.covariance[8]) == pytest.approx((0.0009, 0.0016, 0.0036), rel=0.02)
    assert FRAME.lla_to_enu(f.latitude, f.longitude, f.altitude) == pytest.approx(enu, abs=2e-3)
    vel = [o for o in out if isinstance(o, Velocity)]
    assert (vel[0].east, vel[0].north) == pytest.approx((1.0, 2.0), abs=2e-3)
    assert parser.stats.errors == {}


def test_status_mapping():
    for status, expected in ((FIX, 0), (SBAS_FIX, SBAS_FIX), (GBAS_FIX, GBAS_FIX)):
        out, _ = parse_all(ENC.encode(reading(1.0, (1.0, 1.0, 0.0), status)))
        assert [o.status for o in out if isinstance(o, Fix)] == [expected]


def test_no_fix_epoch():
    r = GpsReading(2.0, NO_FIX, None, (0.0, 0.0, 0.0), (math.nan,) * 3, False, 0, 99.9)
    out, _ = parse_all(ENC.encode(r))
    fixes = [o for o in out if isinstance(o, Fix)]
    assert len(fixes) == 1 and fixes[0].status == NO_FIX and math.isnan(fixes[0].latitude)
    assert not [o for o in out if isinstance(o, Velocity)]


def test_epochs_in_a_row_and_utc_time():
    lines = []
    for k in range(10):
        lines += ENC.encode(reading(0.2 * k, (float(k), 0.0, 0.0)))
    out, parser = parse_all(lines)
    fixes = [o for o in out if isinstance(o, Fix)]
    assert [round(FRAME.lla_to_enu(f.latitude, f.longitude, f.altitude)[0], 3) for f in fixes] == list(map(float, range(10)))
    assert fixes[3].utc == "100000.60"  # utc_epoch is 10:00:00.00 UTC
    assert parser.stats.fixes == 10


def test_without_gst_the_covariance_comes_from_hdop():
    lines = []
    for k in range(3):
        lines += [ln for ln in ENC.encode(reading(1.0 + k, (5.0, 5.0, 0.0))) if not ln.startswith("$GPGST")]
    out, _ = parse_all(lines)
    fixes = [o for o in out if isinstance(o, Fix)]
    assert len(fixes) == 3  # each emitted at its epoch's RMC, not one epoch late
    assert all(f.covariance_type == COVARIANCE_APPROXIMATED for f in fixes)
    assert fixes[0].covariance[0] == pytest.approx((0.7 * 0.02) ** 2)  # HDOP x RTK error


def test_a_missing_gst_does_not_hold_the_fix_beyond_its_epoch():
    first = [ln for ln in ENC.encode(reading(1.0, (1.0, 0.0, 0.0))) if not ln.startswith("$GPGST")]
    out, parser = parse_all(ENC.encode(reading(0.0, (0.0, 0.0, 0.0))) + first + ENC.encode(reading(2.0, (2.0, 0.0, 0.0))))
    fixes = [o for o in out if isinstance(o, Fix)]
    assert [f.covariance_type for f in fixes] == [COVARIANCE_DIAGONAL_KNOWN, COVARIANCE_APPROXIMATED,
                                                  COVARIANCE_DIAGONAL_KNOWN]


def _delivered_at(lines):
    """Each fix with the index of the line that delivered it."""
    parser, out = NmeaFixParser(), []
    for k, line in enumerate(lines):
        out += [(k, f) for f in parser.feed_line(line, 100.0 + k) if isinstance(f, Fix)]
    return out


def test_a_gst_sent_before_its_gga_completes_it_on_arrival():
    """Receivers differ in their sentences' order: GST, RMC, then GGA here."""
    lines = []
    for k in range(3):
        gga, gst, rmc = ENC.encode(reading(1.0 + k, (float(k), 0.0, 0.0)))
        lines += [gst, rmc, gga]
    out = _delivered_at(lines)
    assert [k for k, _ in out] == [2, 5, 8]  # at each GGA, not one epoch later
    assert all(f.covariance_type == COVARIANCE_DIAGONAL_KNOWN for _, f in out)
    assert (out[0][1].covariance[0], out[0][1].covariance[4]) == pytest.approx((0.0009, 0.0016), rel=0.05)


def test_a_receiver_of_gga_alone_delivers_each_fix_on_arrival():
    """GGA only, no GST, no RMC: the first epoch cannot know that nothing completes it (its
    fix leaves with the next GGA); every later fix leaves as it arrives, not a period late."""
    lines = [ENC.encode(reading(1.0 + k, (float(k), 0.0, 0.0)))[0] for k in range(4)]
    out = _delivered_at(lines)
    assert [k for k, _ in out] == [1, 1, 2, 3]
    assert [round(FRAME.lla_to_enu(f.latitude, f.longitude, f.altitude)[0], 3) for _, f in out] == [0.0, 1.0, 2.0, 3.0]
    assert all(f.covariance_type == COVARIANCE_APPROXIMATED for _, f in out)
    assert [f.received for _, f in out] == [100.0, 101.0, 102.0, 103.0]  # stamped at their own GGA


def test_a_gst_after_the_rmc_still_completes_every_later_epoch():
    """GGA, RMC, GST: the first epoch leaves at its RMC (no GST seen yet), the later ones at
    their GST, with its covariance."""
    lines = []
    for k in range(3):
        gga, gst, rmc = ENC.encode(reading(1.0 + k, (float(k), 0.0, 0.0)))
        lines += [gga, rmc, gst]
    out = _delivered_at(lines)
    assert [k for k, _ in out] == [1, 5, 8]
    assert [f.covariance_type for _, f in out] == [COVARIANCE_APPROXIMATED, COVARIANCE_DIAGONAL_KNOWN,
                                                   COVARIANCE_DIAGONAL_KNOWN]


def test_bad_sentences_are_counted_and_skipped():
    good = ENC.encode(reading(1.0, (5.0, 5.0, 0.0)))
    corrupted = good[0][:20] + ("1" if good[0][20] != "1" else "2") + good[0][21:]
    lines = ["garbage line", "$GPXXX,1,2,3*00", corrupted, "", "$GPGGA,broken"] + good
    out, parser = parse_all(lines)
    assert len([o for o in out if isinstance(o, Fix)]) == 1
    assert parser.stats.errors.get("bad checksum", 0) >= 1
    assert parser.stats.errors.get("not a sentence", 0) == 1
    assert sum(parser.stats.errors.values()) >= 3
    assert parser.pop_problems()


def test_sentences_are_valid_nmea():
    for line in ENC.encode(reading(7.0, (1.0, 2.0, 3.0))):
        msg = pynmea2.parse(line, check=True)
        assert msg.talker == "GP"
        assert len(line) <= 82  # NMEA 0183 maximum sentence length, $ and checksum included
