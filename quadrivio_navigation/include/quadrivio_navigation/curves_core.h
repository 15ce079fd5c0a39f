// Curves of a car with a minimum turning radius, shared by the OMPL core (ompl_core.cpp)
// and the lattice search (lattice_core.cpp): Reeds-Shepp words with reverse parts weighted
// and Dubins words, the same formulas as quadrivio_navigation/curves.py (cross-tested by
// test_curves_mprim.py and test_lattice_native.py).
#pragma once

#include <algorithm>
#include <cmath>
#include <limits>

namespace qv_curves
{
const double kTwoPi = 2.0 * M_PI;

// An angle in [-pi, pi): a yaw of exactly pi (a goal "facing west" from a quaternion) made
// RRTConnect find no valid goal state ("Unable to sample any valid states for goal tree").
inline double wrap(double a)
{
    const double w = std::atan2(std::sin(a), std::cos(a));
    return w >= M_PI ? w - kTwoPi : w;
}

inline void advance(double &x, double &y, double &th, char kind, double length, double r)
{
    if (kind == 'S')
    {
        x += length * std::cos(th);
        y += length * std::sin(th);
        return;
    }
    double phi = kind == 'L' ? length / r : -length / r;
    double sign = kind == 'L' ? 1.0 : -1.0;
    x += sign * r * (std::sin(th + phi) - std::sin(th));
    y -= sign * r * (std::cos(th + phi) - std::cos(th));
    th += phi;
}

// ---------------------------------------------------------------------------
// Reeds-Shepp words with reverse parts weighted: the same formulas as OMPL's (Reeds and
// Shepp 1990, 8.1-8.11) and as quadrivio_navigation/curves.py, but choosing the word whose
// length, reverse parts counted `reverse_cost` times, is least. OMPL's own space picks the
// shortest word, which drives backwards as readily as forwards; a vehicle should not.
namespace rs
{
const double kZero = 1e-9;
const double kHalfPi = 0.5 * M_PI;

inline double mod2pi(double x)
{
    double v = std::fmod(x, kTwoPi);
    if (v < -M_PI)
        v += kTwoPi;
    else if (v > M_PI)
        v -= kTwoPi;
    return v;
}

inline void polar(double x, double y, double &r, double &theta)
{
    r = std::hypot(x, y);
    theta = std::atan2(y, x);
}

inline void tauOmega(double u, double v, double xi, double eta, double phi, double &tau, double &omega)
{
    double delta = mod2pi(u - v), A = std::sin(u) - std::sin(delta), B = std::cos(u) - std::cos(delta) - 1.;
    double t1 = std::atan2(eta * A - xi * B, xi * A + eta * B), t2 = 2. * (std::cos(delta) - std::cos(v) - std::cos(u)) + 3;
    tau = (t2 < 0) ? mod2pi(t1 + M_PI) : mod2pi(t1);
    omega = mod2pi(tau - u + v - phi);
}

inline bool LSL(double x, double y, double phi, double &t, double &u, double &v)  // 8.1
{
    polar(x - std::sin(phi), y - 1. + std::cos(phi), u, t);
    if (t >= -kZero)
    {
        v = mod2pi(phi - t);
        return v >= -kZero;
    }
    return false;
}

inline bool LSR(double x, double y, double phi, double &t, double &u, double &v)  // 8.2
{
    double t1, u1;
    polar(x + std::sin(phi), y - 1. - std::cos(phi), u1, t1);
    u1 = u1 * u1;
    if (u1 < 4.)
        return false;
    u = std::sqrt(u1 - 4.);
    t = mod2pi(t1 + std::atan2(2., u));
    v = mod2pi(t - phi);
    return t >= -kZero && v >= -kZero;
}

inline bool LRL(double x, double y, double phi, double &t, double &u, double &v)  // 8.3 / 8.4
{
    double xi = x - std::sin(phi), eta = y - 1. + std::cos(phi), u1, theta;
    polar(xi, eta, u1, theta);
    if (u1 > 4.)
        return false;
    u = -2. * std::asin(.25 * u1);
    t = mod2pi(theta + .5 * u + M_PI);
    v = mod2pi(phi - t + u);
    return t >= -kZero && u <= kZero;
}

inline bool LRLRa(double x, double y, double phi, double &t, double &u, double &v)  // 8.7
{
    double xi = x + std::sin(phi), eta = y - 1. - std::cos(phi), rho = .25 * (2. + std::hypot(xi, eta));
    if (rho > 1.)
        return false;
    u = std::acos(rho);
    tauOmega(u, -u, xi, eta, phi, t, v);
    return t >= -kZero && v <= kZero;
}

inline bool LRLRb(double x, double y, double phi, double &t, double &u, double &v)  // 8.8
{
    double xi = x + std::sin(phi), eta = y - 1. - std::cos(phi), rho = (20. - xi * xi - eta * eta) / 16.;
    if (rho < 0 || rho > 1)
        return false;
    u = -std::acos(rho);
    if (u < -.5 * M_PI)
        return false;
    tauOmega(u, u, xi, eta, phi, t, v);
    return t >= -kZero && v >= -kZero;
}

inline bool LRSL(double x, double y, double phi, double &t, double &u, double &v)  // 8.9
{
    double xi = x - std::sin(phi), eta = y - 1. + std::cos(phi), rho, theta;
    polar(xi, eta, rho, theta);
    if (rho < 2.)
        return false;
    double r = std::sqrt(rho * rho - 4.);
    u = 2. - r;
    t = mod2pi(theta + std::atan2(r, -2.));
    v = mod2pi(phi - .5 * M_PI - t);
    return t >= -kZero && u <= kZero && v <= kZero;
}

inline bool LRSR(double x, double y, double phi, double &t, double &u, double &v)  // 8.10
{
    double xi = x + std::sin(phi), eta = y - 1. - std::cos(phi), rho, theta;
    polar(-eta, xi, rho, theta);
    if (rho < 2.)
        return false;
    t = theta;
    u = 2. - rho;
    v = mod2pi(t + .5 * M_PI - phi);
    return t >= -kZero && u <= kZero && v <= kZero;
}

inline bool LRSLR(double x, double y, double phi, double &t, double &u, double &v)  // 8.11
{
    double xi = x + std::sin(phi), eta = y - 1. - std::cos(phi), rho, theta;
    polar(xi, eta, rho, theta);
    if (rho < 2.)
        return false;
    u = 4. - std::sqrt(rho * rho - 4.);
    if (u > kZero)
        return false;
    t = mod2pi(std::atan2((4. - u) * xi - 2. * eta, -2. * xi + (u - 4.) * eta));
    v = mod2pi(t - phi);
    return t >= -kZero && v >= -kZero;
}

struct Word
{
    char kind[5];
    double len[5];  // in units of the turning radius, signed
    int n = 0;
    double cost = std::numeric_limits<double>::infinity();
};

typedef bool (*Formula)(double, double, double, double &, double &, double &);

// the lengths of a word from (t, u, v) of its formula
enum Shape
{
    TUV,        // t u v
    VUT,        // v u t (backwards)
    T_U_MU_V,   // t u -u v
    T_U_U_V,    // t u u v
    T_MH_U_V,   // t -pi/2 u v
    V_U_MH_T,   // v u -pi/2 t
    T_MH_U_MH_V // t -pi/2 u -pi/2 v
};

inline void consider(Word &best, const char *letters, int n, const double *lens, bool flip, bool reflect, double rc)
{
    double c = 0.0;
    double out[5];
    for (int i = 0; i < n; ++i)
    {
        out[i] = flip ? -lens[i] : lens[i];
        c += out[i] >= 0 ? out[i] : -rc * out[i];
    }
    if (c < best.cost - 1e-12)
    {
        best.cost = c;
        best.n = n;
        for (int i = 0; i < n; ++i)
        {
            char k = letters[i];
            if (reflect)
                k = k == 'L' ? 'R' : (k == 'R' ? 'L' : 'S');
            best.kind[i] = k;
            best.len[i] = out[i];
        }
    }
}

inline void family(Word &best, Formula f, const char *letters, Shape shape, double x, double y, double phi, double rc)
{
    static const double signs[4][3] = {{1, 1, 1}, {-1, 1, -1}, {1, -1, -1}, {-1, -1, 1}};
    static const bool flips[4] = {false, true, false, true}, refl[4] = {false, false, true, true};
    for (int k = 0; k < 4; ++k)
    {
        double t, u, v;
        if (!f(signs[k][0] * x, signs[k][1] * y, signs[k][2] * phi, t, u, v))
            continue;
        double L[5];
        int n = 3;
        switch (shape)
        {
            case TUV: L[0] = t; L[1] = u; L[2] = v; break;
            case VUT: L[0] = v; L[1] = u; L[2] = t; break;
            case T_U_MU_V: L[0] = t; L[1] = u; L[2] = -u; L[3] = v; n = 4; break;
            case T_U_U_V: L[0] = t; L[1] = u; L[2] = u; L[3] = v; n = 4; break;
            case T_MH_U_V: L[0] = t; L[1] = -kHalfPi; L[2] = u; L[3] = v; n = 4; break;
            case V_U_MH_T: L[0] = v; L[1] = u; L[2] = -kHalfPi; L[3] = t; n = 4; break;
            case T_MH_U_MH_V: L[0] = t; L[1] = -kHalfPi; L[2] = u; L[3] = -kHalfPi; L[4] = v; n = 5; break;
        }
        consider(best, letters, n, L, flips[k], refl[k], rc);
    }
}

// The cheapest word to the goal (x, y, phi) in the start's frame, in units of the radius.
inline Word cheapest(double x, double y, double phi, double rc)
{
    Word best;
    double xb = x * std::cos(phi) + y * std::sin(phi), yb = x * std::sin(phi) - y * std::cos(phi);
    family(best, LSL, "LSL", TUV, x, y, phi, rc);
    family(best, LSR, "LSR", TUV, x, y, phi, rc);
    family(best, LRL, "LRL", TUV, x, y, phi, rc);
    family(best, LRL, "LRL", VUT, xb, yb, phi, rc);
    family(best, LRLRa, "LRLR", T_U_MU_V, x, y, phi, rc);
    family(best, LRLRb, "LRLR", T_U_U_V, x, y, phi, rc);
    family(best, LRSL, "LRSL", T_MH_U_V, x, y, phi, rc);
    family(best, LRSR, "LRSR", T_MH_U_V, x, y, phi, rc);
    family(best, LRSL, "LSRL", V_U_MH_T, xb, yb, phi, rc);
    family(best, LRSR, "RSRL", V_U_MH_T, xb, yb, phi, rc);
    family(best, LRSLR, "LRSLR", T_MH_U_MH_V, x, y, phi, rc);
    return best;
}
}  // namespace rs

// ---------------------------------------------------------------------------
// Dubins words (forwards only): LSL, RSR, RSL, LSR, RLR, LRL, the shortest kept; the same
// formulas as OMPL's DubinsStateSpace and quadrivio_navigation/curves.py. Ours because
// Debian's libompl is built with assertions on, and OMPL's dubinsLSR asserts a
// round-off bound that some pose pairs miss: one such pair aborted the whole process
// (about 1 run in 20 of the forward-only planner test).
namespace dubins
{
inline double m2pi(double x)  // to [0, 2 pi)
{
    return x - kTwoPi * std::floor(x / kTwoPi);
}

inline void consider(rs::Word &best, const char *letters, double t, double p, double q)
{
    double cost = t + p + q;
    if (!(cost < best.cost))
        return;
    best.n = 3;
    best.cost = cost;
    for (int i = 0; i < 3; ++i)
        best.kind[i] = letters[i];
    best.len[0] = t;
    best.len[1] = p;
    best.len[2] = q;
}

// The shortest word from (0, 0, th0) to (dx, dy, th1), lengths in units of the radius.
inline rs::Word shortest(double dx, double dy, double th0, double th1)
{
    const double zero = -1e-7;  // OMPL's DUBINS_ZERO: a straight of length 0 is a word too
    double d = std::hypot(dx, dy);
    double th = d > 1e-12 ? std::atan2(dy, dx) : 0.0;
    double a = m2pi(th0 - th), b = m2pi(th1 - th);
    double sa = std::sin(a), sb = std::sin(b), ca = std::cos(a), cb = std::cos(b), cab = std::cos(a - b);
    rs::Word best;
    double tmp = 2. + d * d - 2. * cab + 2. * d * (sa - sb);
    if (tmp >= zero)
    {
        double theta = std::atan2(cb - ca, d + sa - sb);
        consider(best, "LSL", m2pi(theta - a), std::sqrt(std::max(tmp, 0.)), m2pi(b - theta));
    }
    tmp = 2. + d * d - 2. * cab + 2. * d * (sb - sa);
    if (tmp >= zero)
    {
        double theta = std::atan2(ca - cb, d - sa + sb);
        consider(best, "RSR", m2pi(a - theta), std::sqrt(std::max(tmp, 0.)), m2pi(theta - b));
    }
    tmp = d * d - 2. + 2. * cab - 2. * d * (sa + sb);
    if (tmp >= zero)
    {
        double p = std::sqrt(std::max(tmp, 0.));
        double theta = std::atan2(ca + cb, d - sa - sb) - std::atan2(2., p);
        consider(best, "RSL", m2pi(a - theta), p, m2pi(b - theta));
    }
    tmp = -2. + d * d + 2. * cab + 2. * d * (sa + sb);
    if (tmp >= zero)
    {
        double p = std::sqrt(std::max(tmp, 0.));
        double theta = std::atan2(-ca - cb, d + sa + sb) - std::atan2(-2., p);
        consider(best, "LSR", m2pi(theta - a), p, m2pi(theta - b));
    }
    tmp = (6. - d * d + 2. * cab + 2. * d * (sa - sb)) / 8.;
    if (std::fabs(tmp) <= 1.)
    {
        double p = m2pi(kTwoPi - std::acos(tmp));
        double theta = std::atan2(ca - cb, d - sa + sb);
        double t = m2pi(a - theta + .5 * p);
        consider(best, "RLR", t, p, m2pi(a - b - t + p));
    }
    tmp = (6. - d * d + 2. * cab + 2. * d * (sb - sa)) / 8.;
    if (std::fabs(tmp) <= 1.)
    {
        double p = m2pi(kTwoPi - std::acos(tmp));
        double theta = std::atan2(ca - cb, d + sa - sb);
        double t = m2pi(-a - theta + .5 * p);
        consider(best, "LRL", t, p, m2pi(b - a - t + p));
    }
    return best;
}
}  // namespace dubins

}  // namespace qv_curves
