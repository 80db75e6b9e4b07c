# 1-D hydrostatics, tube with non-uniform stretch: (P_k - P_{k-1}) Q(s_k) = mbar_k Phi'(s_k)
# Phi' from a C^1 Catmull-Rom centreline (as in the coupled model) or from one-sided chords.
import numpy as np, math
from scipy.optimize import root
L=1.0; gam=1.4; K=1.0; A=1.0; Om2=3.0
stretch=lambda s: 1+0.4*s+0.3*np.sin(3*s)
xpos=lambda s: s+0.2*s*s-0.1*(np.cos(3*s)-1)          # x' = stretch
def CRd(t): return np.array([0.5*(-3*t*t+4*t-1),0.5*(9*t*t-10*t),0.5*(-9*t*t+8*t+1),0.5*(3*t*t-2*t)])
def CR(t): return np.array([0.5*(-t**3+2*t**2-t),0.5*(3*t**3-5*t**2+2),0.5*(-3*t**3+4*t**2+t),0.5*(t**3-t**2)])
def run(N,Qvar,Xvar,shift=0.0):
    ds=L/N; M=N; sn=np.arange(N+1)*ds; xn=xpos(sn)
    xg=np.concatenate([[3*xn[0]-3*xn[1]+xn[2]],xn,[3*xn[-1]-3*xn[-2]+xn[-3]]])
    Ge=np.abs(np.diff(xn))/ds                                       # element stretch (chord)
    gj=np.empty(N+1); gj[1:-1]=0.5*(Ge[:-1]+Ge[1:]); gj[0]=Ge[0]; gj[-1]=Ge[-1]
    def loc(x):
        e=np.clip(np.floor(x/ds).astype(int),0,N-1); return e,x/ds-e
    def gam_s(x):
        e,t=loc(x)
        return Ge[e] if Qvar=="A" else gj[e]*(1-t)+gj[e+1]*t
    def Vol(a,b):
        pts=np.unique(np.concatenate([[a,b],sn[(sn>a)&(sn<b)]]))
        mid=0.5*(pts[:-1]+pts[1:]); return float(np.sum(A*gam_s(mid)*np.diff(pts)))
    def X(s):
        e,t=loc(np.atleast_1d(s)); return np.array([CR(ti)@xg[ei:ei+4] for ei,ti in zip(e,t)])
    def Xp(s):
        e,t=loc(np.atleast_1d(s))
        if Xvar=="CR": return np.array([CRd(ti)@xg[ei:ei+4]/ds for ei,ti in zip(e,t)])
        return (xn[e+1]-xn[e])/ds
    xc=0.5*(xn[0]+xn[-1])
    Phip=lambda s: Om2*(X(s)-xc)*Xp(s)
    s0=np.linspace(0,L,M+1); s0[1:-1]+=shift*ds
    m=np.array([Vol(s0[k],s0[k+1]) for k in range(M)]); mb=np.zeros(M+1); mb[:-1]+=m/2; mb[1:]+=m/2
    def res(si):
        s=np.concatenate([[0],si,[L]])
        V=np.array([Vol(s[k],s[k+1]) for k in range(M)]); P=K*(m/V)**gam
        return ((P[1:]-P[:-1])*A*gam_s(s[1:-1])-mb[1:-1]*Phip(s[1:-1]))
    sol=root(res,s0[1:-1],method='hybr',tol=1e-14)
    s=np.concatenate([[0],sol.x,[L]])
    V=np.array([Vol(s[k],s[k+1]) for k in range(M)]); P=K*(m/V)**gam
    c=0.5*(s[:-1]+s[1:]); Phi=0.5*Om2*(X(c)-xc)**2
    H=gam/(gam-1)*K**(1/gam)*P**((gam-1)/gam)-Phi
    return np.max(np.abs(H-H.mean()))/np.max(Phi), np.max(np.abs(res(sol.x)))
for Qv,Xv in (("A","chord"),("A","CR"),("B","CR")):
  for sh in (0.0,0.3):
    out=[run(N,Qv,Xv,sh) for N in (20,40,80,160)]
    errs=[o[0] for o in out]
    print(Qv,Xv,"shift",sh,["%.2e"%e for e in errs],"orders",["%.2f"%math.log2(a/b) for a,b in zip(errs[:-1],errs[1:])],"maxres %.1e"%max(o[1] for o in out))
