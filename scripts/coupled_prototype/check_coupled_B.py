
import numpy as np, math
from varint.lattice.lie import cay, cay_inv, hat
rng=np.random.default_rng(3)
N=6; L=1.2; ds=L/N; M=9; h=0.05
rhoA=0.7; Iner=np.array([0.02,0.01,0.01]); Jst=np.array([3.,2.,2.5]); Kst=np.array([50.,30.,40.])
a_w=0.3; beta1=0.5; beta2=20.; R0=0.1; pext=0.3; gam=1.4
w=np.full(N+1,ds); w[0]=w[-1]=ds/2
m=rng.uniform(0.5,1.0,M)*0.01; S=rng.uniform(-0.1,0.1,M)
mbar=np.zeros(M+1); mbar[:-1]+=m/2; mbar[1:]+=m/2
g=np.array([0.3,-0.2,-9.81])
CHI=np.array([1.,0,0])
def CR(t):  # Catmull-Rom weights for nodes e-1,e,e+1,e+2
    return np.array([0.5*(-t**3+2*t**2-t),0.5*(3*t**3-5*t**2+2),0.5*(-3*t**3+4*t**2+t),0.5*(t**3-t**2)])
def X(s,r):
    e=min(max(int(math.floor(s/ds)),0),N-1); t=s/ds-e
    Wt=CR(t); pts=[]
    for i,wi in zip(range(e-1,e+3),Wt):
        if i<0: ri=3*r[0]-3*r[1]+r[2]
        elif i>N: ri=3*r[N]-3*r[N-1]+r[N-2]
        else: ri=r[i]
        pts.append(wi*ri)
    return sum(pts)
def strains(Lam,r):
    Om=np.array([cay_inv(Lam[j].T@Lam[j+1])/ds for j in range(N)])
    Ga=np.array([0.5*(Lam[j]+Lam[j+1]).T@(r[j+1]-r[j])/ds for j in range(N)])
    return Om,Ga
def gfun(a,b,t): d=b-a; return ds*math.pi*(a*a*t+a*d*t*t+d*d*t**3/3)
def h1(t,a,b): d=b-a; return a*a*t*t/2+2*a*d*t**3/3+d*d*t**4/4
def h0(t,a,b): d=b-a; return a*a*t+a*d*t*t+d*d*t**3/3-h1(t,a,b)
VARIANT="B"
def vols(s,R,G):  # G = |Gamma_e| per element; variant B: continuous nodal stretch
    if VARIANT=="A": return volsA(s,R,G)
    gj=np.empty(N+1); gj[1:-1]=0.5*(G[:-1]+G[1:]); gj[0]=G[0]; gj[-1]=G[-1]
    V=[]
    for k in range(M):
        v=0.0
        for e in range(N):
            t0=min(max(s[k]/ds-e,0),1); t1=min(max(s[k+1]/ds-e,0),1)
            if t1>t0: v+=ds*math.pi*(gj[e]*(h0(t1,R[e],R[e+1])-h0(t0,R[e],R[e+1]))+gj[e+1]*(h1(t1,R[e],R[e+1])-h1(t0,R[e],R[e+1])))
        V.append(v)
    return np.array(V)
def volsA(s,R,G):  # G = |Gamma_e| per element
    V=[]
    for k in range(M):
        def loc(x):
            e=min(max(int(math.floor(x/ds)),0),N-1); return e,x/ds-e
        e0,t0=loc(s[k]); e1,t1=loc(s[k+1])
        v=sum(G[e]*ds*math.pi*(R[e]**2+R[e]*R[e+1]+R[e+1]**2)/3 for e in range(e0,e1))
        v+=G[e1]*gfun(R[e1],R[e1+1],t1)-G[e0]*gfun(R[e0],R[e0+1],t0)
        V.append(v)
    return np.array(V)
def VolT(R,G):
    gj=np.empty(N+1); gj[1:-1]=0.5*(G[:-1]+G[1:]); gj[0]=G[0]; gj[-1]=G[-1]
    a,b=R[:-1],R[1:]
    return np.sum(ds*math.pi*(gj[:-1]*(3*a*a+2*a*b+b*b)+gj[1:]*(a*a+2*a*b+3*b*b))/12)
def pres(V): return np.exp(S)*(m/V)**gam
def U(s,R,r,Om,Ga,grav):
    G=np.sqrt((Ga*Ga).sum(1))
    V=vols(s,R,G)
    u=np.sum(ds*(0.5*(Jst*Om*Om).sum(1)+0.5*(Kst*(Ga-CHI)**2).sum(1)))
    u+=np.sum(pres(V)*V/(gam-1))
    u+=0.5*beta1*ds*np.sum(((R[1:]-R[:-1])/ds)**2)+0.5*beta2*np.sum(w*(R-R0)**2)
    u+=pext*VolT(R,G)
    if grav:
        u-=g@(rhoA*(w[:,None]*r).sum(0)+sum(mbar[k]*X(s[k],r) for k in range(M+1)))
    return u
def Ld(q0,q1,grav=True):
    r0,L0,R0_,s0=q0; r1,L1,R1,s1=q1
    xi=np.array([cay_inv(L0[j].T@L1[j]) for j in range(N+1)])
    K=0.5*rhoA*np.sum(w*((r1-r0)**2).sum(1))/h**2+0.5*np.sum(w*(Iner*xi*xi).sum(1))/h**2
    K+=0.5*a_w*np.sum(w*(R1-R0_)**2)/h**2
    K+=0.5*sum(mbar[k]*np.sum((X(s1[k],r1)-X(s0[k],r0))**2) for k in range(M+1))/h**2
    Om0,Ga0=strains(L0,r0); Om1,Ga1=strains(L1,r1)
    sm=(s0+s1)/2; Rm=(R0_+R1)/2; rm=(r0+r1)/2
    return h*(K-U(sm,Rm,rm,(Om0+Om1)/2,(Ga0+Ga1)/2,grav))
# random configuration: bent rod
def config(seed):
    rr=np.random.default_rng(seed)
    Lam=np.empty((N+1,3,3)); r=np.zeros((N+1,3)); Lam[0]=cay(rr.normal(size=3)*0.3)
    for j in range(N):
        Lam[j+1]=Lam[j]@cay(ds*rr.normal(size=3))
        r[j+1]=r[j]+Lam[j]@(CHI+0.05*rr.normal(size=3))*ds
    R=R0*(1+0.05*rr.normal(size=N+1))
    s=np.linspace(0,L,M+1); s[1:-1]+=0.3*ds*rr.uniform(-1,1,M-1)
    return [r,Lam,R,s]
q0=config(5)
q1=[q0[0]+0.01*rng.normal(size=q0[0].shape),np.array([q0[1][j]@cay(0.05*rng.normal(size=3)) for j in range(N+1)]),
    q0[2]+0.001*rng.normal(size=N+1),q0[3].copy()]
q1[3][1:-1]+=0.05*ds*rng.normal(size=M-1)
# (a) invariance without gravity
Q=cay(rng.normal(size=3)); c=rng.normal(size=3)
tr=lambda q:[q[0]@Q.T+c,np.array([Q@Lj for Lj in q[1]]),q[2],q[3]]
print("invariance", Ld(q0,q1,False), Ld(tr(q0),tr(q1),False))
# (b) FD derivatives wrt r at each level
eps=1e-6
def dr(level,grav=True):
    out=np.zeros((N+1,3))
    for j in range(N+1):
        for d in range(3):
            qa=[x.copy() for x in (q0 if level==0 else q1)]; qb=[x.copy() for x in qa]
            qa[0][j,d]+=eps; qb[0][j,d]-=eps
            if level==0: out[j,d]=(Ld(qa,q1,grav)-Ld(qb,q1,grav))/(2*eps)
            else: out[j,d]=(Ld(q0,qa,grav)-Ld(q0,qb,grav))/(2*eps)
    return out
D1=dr(0); D2=dr(1)
Mtot=rhoA*L+m.sum()
print("sum D1+D2", (D1+D2).sum(0), "h M g", h*Mtot*g)
v=(q1[0]-q0[0])/h
vX=np.array([(X(q1[3][k],q1[0])-X(q0[3][k],q0[0]))/h for k in range(M+1)])
phys=rhoA*(w[:,None]*v).sum(0)+(mbar[:,None]*vX).sum(0)
print("P_{n+1}", D2.sum(0), phys+0.5*h*Mtot*g)
print("P_n    ", -D1.sum(0), phys-0.5*h*Mtot*g)
# (d) angular momentum decomposition without gravity, level n+1
D2ng=dr(1,False)
def dsig(level,grav=False):
    out=np.zeros((N+1,3))
    for j in range(N+1):
        for d in range(3):
            sg=np.zeros(3); sg[d]=eps
            qa=[x.copy() for x in (q0 if level==0 else q1)]; qb=[x.copy() for x in qa]
            qa[1][j]=qa[1][j]@cay(sg); qb[1][j]=qb[1][j]@cay(-sg)
            if level==0: out[j,d]=(Ld(qa,q1,grav)-Ld(qb,q1,grav))/(2*eps)
            else: out[j,d]=(Ld(q0,qa,grav)-Ld(q0,qb,grav))/(2*eps)
    return out
Pi1=dsig(1)
J=np.cross(q1[0],D2ng).sum(0)+sum(q1[1][j]@Pi1[j] for j in range(N+1))
xi=np.array([cay_inv(q0[1][j].T@q1[1][j]) for j in range(N+1)])
Jphys=np.cross(q1[0],rhoA*w[:,None]*v).sum(0)+sum(q1[1][j]@((np.eye(3)-hat(xi[j])/2+np.outer(xi[j],xi[j])/4)@(w[j]*Iner*xi[j]/h)) for j in range(N+1))
Jphys+=sum(mbar[k]*np.cross(X(q1[3][k],q1[0]),vX[k]) for k in range(M+1))
print("J_{n+1}", J, Jphys)
D1ng=dr(0,False); Pi0=dsig(0)
Jn=np.cross(q0[0],-D1ng).sum(0)+sum(q0[1][j]@(-Pi0[j]) for j in range(N+1))
print("J_n    ", Jn)
# label momentum at n+1
def Xp(s,r,e_=1e-7): return (X(s+e_,r)-X(s-e_,r))/(2*e_)
Om0,Ga0=strains(q0[1],q0[0]); Om1,Ga1=strains(q1[1],q1[0]); Gb=np.sqrt((((Ga0+Ga1)/2)**2).sum(1))
sm=(q0[3]+q1[3])/2; Rm=(q0[2]+q1[2])/2; rm=(q0[0]+q1[0])/2
V=vols(sm,Rm,Gb); P=pres(V)
for k in (2,5):
    qa=[x.copy() for x in q1]; qb=[x.copy() for x in q1]; qa[3][k]+=eps; qb[3][k]-=eps
    fd=(Ld(q0,qa)-Ld(q0,qb))/(2*eps)
    e=int(sm[k]//ds); t=sm[k]/ds-e; Rk=Rm[e]*(1-t)+Rm[e+1]*t
    gj=np.empty(N+1); gj[1:-1]=0.5*(Gb[:-1]+Gb[1:]); gj[0]=Gb[0]; gj[-1]=Gb[-1]
    Qk=math.pi*Rk**2*(gj[e]*(1-t)+gj[e+1]*t)
    form=mbar[k]*vX[k]@Xp(q1[3][k],q1[0])-h/2*((P[k]-P[k-1])*Qk-mbar[k]*g@Xp(sm[k],rm))
    print("p_s", k, fd, form)
# C1 check of Catmull-Rom across nodes, incl. end elements
r=q0[0]
for j in (1,2,N-1):
    print("X' jump at node",j, np.abs(Xp(j*ds-1e-5,r,1e-8)-Xp(j*ds+1e-5,r,1e-8)).max())
print("partition, linear repro:", X(0.37, np.outer(np.arange(N+1)*ds,[1,2,3])+5), 0.37*np.array([1,2,3])+5)
# volume vs quadrature
from scipy.integrate import quad
def Rint(x,R):
    e=min(int(x//ds),N-1); t=x/ds-e; return R[e]*(1-t)+R[e+1]*t
k=3; lo,hi=sm[k],sm[k+1]
pts=[lo]+[j*ds for j in range(N+1) if lo<j*ds<hi]+[hi]
vq=sum(quad(lambda x: math.pi*Rint(x,Rm)**2*Gb[min(int(x//ds),N-1)],a,b,epsrel=1e-13)[0] for a,b in zip(pts[:-1],pts[1:]))
print("V_k (B vs A quad skipped)", V[k])
