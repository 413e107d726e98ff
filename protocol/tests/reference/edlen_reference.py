"""Independent re-derivation of the Birch & Downs (1994) refractive index of air, in 40-digit
decimal arithmetic, for protocol/tests/conversions.rs.

Written separately from protocol/src/edlen.rs (different language, different arithmetic,
equations typed again from Birch & Downs, Metrologia 31 (1994) 315, eqs. 1-3, and IAPWS-IF97
eq. 30 for the saturation vapour pressure). Run: python3 edlen_reference.py
"""
from decimal import Decimal as D, getcontext

getcontext().prec = 40

# IAPWS-IF97, region 4, saturation-pressure equation (eq. 30), coefficients n1..n10.
N = [D("0.11670521452767e4"), D("-0.72421316703206e6"), D("-0.17073846940092e2"),
     D("0.12020824702470e5"), D("-0.32325550322333e7"), D("0.14915108613530e2"),
     D("-0.48232657361591e4"), D("0.40511340542057e6"), D("-0.23855557567849"),
     D("0.65017534844798e3")]


def psat_pa(t_c):
    T = D(t_c) + D("273.15")
    th = T + N[8] / (T - N[9])
    A = th * th + N[0] * th + N[1]
    B = N[2] * th * th + N[3] * th + N[4]
    C = N[5] * th * th + N[6] * th + N[7]
    x = 2 * C / (-B + (B * B - 4 * A * C).sqrt())
    return D(10) ** 6 * x ** 4


def n_bd(lam_nm, t_c, p_pa, rh_pct):
    s2 = (D(1000) / D(lam_nm)) ** 2
    t = D(t_c)
    p = D(p_pa)
    ns = (D("8342.54") + D(2406147) / (D(130) - s2) + D(15998) / (D("38.9") - s2)) / D(10) ** 8
    ntp = p * ns / D("96095.43") * (1 + (D("0.601") - D("0.00972") * t) * p / D(10) ** 8) \
        / (1 + D("0.0036610") * t)
    f = D(rh_pct) / 100 * psat_pa(t_c)
    return 1 + ntp - f * (D("3.7345") - D("0.0401") * s2) / D(10) ** 10


if __name__ == "__main__":
    for t_k in ("300", "500", "600"):
        print("psat", t_k, "K:", psat_pa(D(t_k) - D("273.15")) / D(10) ** 6, "MPa")
    for (t, p, rh) in [(15, 101325, 0), (15, 101325, 50), (20, 101325, 0), (20, 101325, 50),
                       (20, 99000, 30), (22.5, 100500, 45), (25, 101325, 50), (25, 102000, 80),
                       (30, 101325, 50), (30, 98000, 20)]:
        print(f"({t}, {p}, {rh}) -> {n_bd('632.991', str(t), str(p), str(rh)):.15f}")
